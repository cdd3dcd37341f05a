"""The code's shape, for the closing notes of redesigns: import cycles (lazy imports and
type hints counted), long modules and long functions.

    python benchmarks/code_shape.py [--limit 400]

Prints one figure a line; the import graph comes from ``tests/importgraph.py`` (AST).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import importgraph as g  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--limit", type=int, default=400, help="module length that counts as long")
    args = parser.parse_args()
    edges = g.imports()
    modules = g.strongly_connected(g.import_graph(edges))
    packages = g.strongly_connected(g.import_graph(edges, packages=True))
    print(f"module cycles: {len(modules)}")
    for cycle in modules:
        print("  " + " <-> ".join(cycle))
    print(f"package cycles: {len(packages)}")
    for cycle in packages:
        print(f"  {len(cycle)} packages: " + ", ".join(cycle))
    lengths = {name: len(path.read_text().splitlines())
               for name, path in g.module_files().items()}
    long = sorted(((n, name) for name, n in lengths.items() if n > args.limit), reverse=True)
    print(f"modules over {args.limit} lines: {len(long)}")
    for n, name in long:
        print(f"  {n} {name}")
    n, name = g.function_lengths()[0]
    print(f"longest function: {n} lines, {name}")


if __name__ == "__main__":
    main()
