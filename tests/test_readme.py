"""The README and the docs pages: the README's Python example runs as written, the README
stays short with its set-up commands and one example and picture per capability, every
relative link resolves, and every command's options are on its docs page."""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
TIMEOUT_S = 240
INSTALL_AND_DEMO = 'python3 -m pip install -e . && lodsprite demo'
INSTALL_AND_TEST = ('python3 -m pip install -e ".[test]" && '
                    'python3 -m pytest -q -n 2 --dist loadfile')
# Each command's page under docs/commands/ (the subcommands of one group share one).
PAGES = {"keys": "serve"}  # else a command's own page; a group's subcommands share the group's
GROUPS = ("lumigraph", "scene")  # command groups: their subcommands' options are checked
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def section(text: str, heading: str) -> str:
    """The text under a heading line (``## X``), up to the next heading of its level."""
    level = heading.split(" ", 1)[0]
    start = text.index(f"\n{heading}\n") + len(heading) + 2
    end = re.search(rf"^{level} ", text[start:], flags=re.MULTILINE)
    return text[start:start + end.start()] if end else text[start:]


def first_python_block(text: str, heading: str = "## Python API") -> str:
    """The first ```python block after ``heading``, within its section."""
    match = re.search(r"^```python\n(.*?)^```", section(text, heading),
                      flags=re.MULTILINE | re.DOTALL)
    assert match, f"no ```python block under {heading!r} in {README}"
    return match.group(1)


def test_python_api_example_runs(tmp_path: Path) -> None:
    code = first_python_block(README.read_text(encoding="utf-8"))
    before = set(tmp_path.iterdir())
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                          text=True, timeout=TIMEOUT_S)
    assert proc.returncode == 0, f"README example failed:\n{proc.stdout}\n{proc.stderr}"
    assert "keyframes" in proc.stdout
    pngs = sorted(p for p in set(tmp_path.iterdir()) - before if p.suffix == ".png")
    assert pngs, f"README example wrote no PNG in {tmp_path}"
    for png in pngs:
        assert_a_picture(png)


def assert_a_picture(png: Path) -> None:
    """``png`` is an RGB(A) image that is not one flat colour."""
    with Image.open(png) as im:
        pixels = np.asarray(im.convert("RGB"))
    assert pixels.ndim == 3 and pixels.shape[2] == 3
    assert (pixels != pixels[0, 0]).any(), f"{png.name} is a uniform image"


def test_readme_is_short_and_keeps_the_set_up_commands() -> None:
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 400
    bash = re.findall(r"^```bash\n(.*?)^```", text, flags=re.MULTILINE | re.DOTALL)
    assert INSTALL_AND_DEMO in [b.strip() for b in bash]
    assert INSTALL_AND_TEST in [b.strip() for b in bash]
    assert INSTALL_AND_TEST.split(" && ")[1] in (ROOT / ".ci" / "run").read_text()


def test_each_capability_has_a_command_and_a_picture() -> None:
    text = README.read_text(encoding="utf-8")
    capabilities = re.split(r"^### ", section(text, "## What it does"), flags=re.MULTILINE)[1:]
    assert len(capabilities) >= 7, "LOD-sprite, window, large terrain, distributed, LOD " \
                                   "matching, lumigraph, LODManager"
    for cap in capabilities:
        name = cap.splitlines()[0]
        assert re.search(r"^```bash\n\s*(xvfb-run -a )?lodsprite ", cap, flags=re.MULTILINE), \
            f"no lodsprite command under {name!r}"
        pictures = re.findall(r"!\[[^\]]*\]\((docs/images/[^)]+\.png)\)", cap)
        assert pictures, f"no picture under {name!r}"
        for picture in pictures:
            assert_a_picture(ROOT / picture)
        assert re.search(r"\]\(docs/[^)]+\.md[^)]*\)", cap), f"no docs link under {name!r}"


def markdown_files() -> list[Path]:
    return [README, *sorted(DOCS.rglob("*.md"))]


def test_every_relative_link_points_to_a_file() -> None:
    broken = []
    for md in markdown_files():
        text = re.sub(r"^```.*?^```", "", md.read_text(encoding="utf-8"),
                      flags=re.MULTILINE | re.DOTALL)  # code blocks hold no links
        for target in LINK.findall(text):
            if re.match(r"^[a-z]+:", target) or target.startswith("#"):
                continue  # an address, or an anchor on the same page
            path = (md.parent / target.split("#", 1)[0]).resolve()
            if not path.is_file():
                broken.append(f"{md.relative_to(ROOT)}: {target}")
    assert not broken, "links to missing files:\n" + "\n".join(broken)


def test_the_link_check_sees_a_broken_link(tmp_path: Path) -> None:
    md = tmp_path / "page.md"
    md.write_text("[a](missing.md) [b](https://example.org/x) ![c](#top)\n")
    targets = LINK.findall(md.read_text())
    assert targets == ["missing.md", "https://example.org/x", "#top"]
    assert not (md.parent / targets[0]).is_file()


def test_every_docs_page_is_in_the_site_navigation() -> None:
    config = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    pages = {p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*.md")}
    listed = set(re.findall(r"^\s*-\s+(?:[^:\n]+:\s+)?([\w./-]+\.md)\s*$", config,
                            flags=re.MULTILINE))
    assert pages == listed, f"not in nav: {pages - listed}; missing: {listed - pages}"


def test_every_python_block_in_the_docs_compiles() -> None:
    for md in markdown_files():
        blocks = re.findall(r"^```python\n(.*?)^```", md.read_text(encoding="utf-8"),
                            flags=re.MULTILINE | re.DOTALL)
        for i, block in enumerate(blocks):
            compile(block, f"{md.relative_to(ROOT)} block {i}", "exec",  # notebook cells
                    flags=ast.PyCF_ALLOW_TOP_LEVEL_AWAIT)  # may await at the top level


def cli_help(*commands: str) -> dict[str, str]:
    """``lodsprite COMMAND --help`` for each command, in one interpreter, through the
    console script's own entry point (pyproject.toml)."""
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    module, func = scripts["lodsprite"].split(":")
    driver = (
        "import importlib, sys\n"
        f"main = getattr(importlib.import_module({module!r}), {func!r})\n"
        f"for cmd in {list(commands)!r}:\n"
        "    print('=== ' + cmd, flush=True)\n"
        "    sys.argv = ['lodsprite', *cmd.split(), '--help']\n"
        "    try:\n"
        "        main()\n"
        "    except SystemExit:\n"
        "        pass\n"
        "    sys.stdout.flush()\n")
    proc = subprocess.run([sys.executable, "-c", driver], capture_output=True, text=True,
                          timeout=TIMEOUT_S, env={**os.environ, "COLUMNS": "200", "NO_COLOR": "1"})
    assert proc.returncode == 0, proc.stderr
    parts = re.split(r"^=== (.*)$", proc.stdout, flags=re.MULTILINE)[1:]
    return dict(zip(parts[::2], parts[1::2], strict=True))


def commands_in(help_text: str) -> list[str]:
    """The command names a group's ``--help`` lists (rich's panel or click's plain list)."""
    panel = help_text[help_text.index("Commands"):]
    return re.findall(r"^(?:\s*│ |  )([a-z][\w-]*) ", panel, flags=re.MULTILINE)


@pytest.fixture(scope="module")
def helps() -> dict[str, str]:
    commands = commands_in(cli_help("")[""])
    assert "render" in commands and "lumigraph" in commands, commands
    groups = cli_help(*commands)
    subs = [f"{g} {c}" for g in GROUPS if g in groups for c in commands_in(groups[g])]
    assert "lumigraph render" in subs, groups["lumigraph"]
    return {**{c: h for c, h in groups.items() if c not in GROUPS}, **cli_help(*subs)}


def test_every_command_and_option_is_on_its_docs_page(helps: dict[str, str]) -> None:
    missing = []
    index = (DOCS / "commands" / "index.md").read_text(encoding="utf-8")
    for command, text in helps.items():
        page = DOCS / "commands" / f"{PAGES.get(command, command.split()[0])}.md"
        assert page.is_file(), f"no docs page for lodsprite {command}"
        assert f"lodsprite {command.split()[0]}" in index
        body = page.read_text(encoding="utf-8")
        for option in sorted(set(re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", text)) - {"--help"}):
            if f"`{option}`" not in body:
                missing.append(f"lodsprite {command} {option} ({page.relative_to(ROOT)})")
    assert not missing, "options not documented:\n" + "\n".join(missing)
