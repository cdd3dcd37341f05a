"""The README's first Python example runs as written, from a fresh interpreter."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image

README = Path(__file__).resolve().parents[1] / "README.md"
TIMEOUT_S = 240


def first_python_block(text: str, heading: str = "## Python API") -> str:
    """The first ```python block after ``heading`` (a level-2 heading line), within its
    section."""
    start = text.index(f"\n{heading}\n")
    section = text[start + len(heading) + 2:]
    end = re.search(r"^## ", section, flags=re.MULTILINE)
    section = section[:end.start()] if end else section
    match = re.search(r"^```python\n(.*?)^```", section, flags=re.MULTILINE | re.DOTALL)
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
        with Image.open(png) as im:
            pixels = np.asarray(im.convert("RGB"))
        assert pixels.ndim == 3 and pixels.shape[2] == 3
        assert (pixels != pixels[0, 0]).any(), f"{png.name} is a uniform image"
