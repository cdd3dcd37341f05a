"""Make the notebook page's pictures (docs/images/notebook_*.png): examples/notebook.ipynb
run in JupyterLab 4 in headless Chromium, each widget's output photographed as the
browser shows it.

JupyterLab is started as the notebook tests start it (``tests/notebook/lab_fixtures.py``)
in a temporary folder holding a copy of the notebook (without its closing cells, so the
widgets still show) and ``battlefield.toml``; a last cell written here saves what the
kernel read back (``w.stats`` of each widget, whether a front end showed them) to
``shots.json``, printed at the end.  Needs the ``notebook`` and ``test`` extras and
Debian's chromium and chromium-driver.  About 90 s on 2 CPU cores.  Usage::

    python3 docs/make_notebook_shots.py [--out docs/images]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from io import BytesIO
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "notebook")]

from lab_fixtures import jupyterlab  # noqa: E402

from browsers import quit_browser, start_browser  # noqa: E402

DEADLINE_S = 360.0
MAX_BYTES = 200_000
#: picture name -> the notebook cell (id) whose output it shows
SHOTS = {"terrain": "terrain", "battlefield": "battle", "lightfield": "light",
         "error": "error"}
REPORT = """
import json
json.dump({"front_end": front_end, "seen_after_s": seen_after_s,
           **{name: {k: v for k, v in w.stats.items() if k != "rfb"}
              for name, w in (("terrain", terrain), ("battle", battle), ("light", light))}},
          open("shots.json", "w"), default=str)
"""


def notebook_copy(folder: Path) -> list[str]:
    """The example without its closing cells, a report cell at its end, and a clock on
    the front-end wait, written to ``folder``; the cell ids in order."""
    import nbformat

    nb = nbformat.read(ROOT / "examples" / "notebook.ipynb", as_version=4)
    nb.cells = [c for c in nb.cells if not c.id.startswith("close")]
    for cell in nb.cells:
        if cell.id == "played":
            cell.source = ("import time\nt0 = time.perf_counter()\n" + cell.source.replace(
                "front_end = await shown(terrain)\n",
                "front_end = await shown(terrain)\nseen_after_s = time.perf_counter() - t0\n"))
    nb.cells.append(nbformat.v4.new_code_cell(REPORT.strip()))
    nbformat.write(nb, folder / "notebook.ipynb")
    shutil.copy(ROOT / "examples" / "battlefield.toml", folder)
    return [c.id for c in nb.cells]


def small_png(png: bytes) -> bytes:
    """``png`` as is, or in 256 colours when larger than :data:`MAX_BYTES`."""
    from PIL import Image

    if len(png) <= MAX_BYTES:
        return png
    out = BytesIO()
    Image.open(BytesIO(png)).convert("RGB").quantize(256).save(out, "PNG", optimize=True)
    return out.getvalue()


def run_in_lab(folder: Path, ids: list[str], out: Path) -> dict:
    """Run every cell in JupyterLab, then photograph the outputs named in :data:`SHOTS`."""
    from selenium.webdriver.common.by import By

    driver = profile = None
    with jupyterlab(folder, DEADLINE_S) as (base, token):
        try:
            driver, profile = start_browser(DEADLINE_S, (1100, 4800))  # every output in sight
            driver.get(f"{base}/lab/tree/notebook.ipynb?token={token}")
            end = time.monotonic() + DEADLINE_S
            while driver.execute_script(
                    "const w = window.jupyterapp && window.jupyterapp.shell.currentWidget;"
                    "const k = w && w.sessionContext && w.sessionContext.session"
                    " && w.sessionContext.session.kernel; return k && k.status") != "idle":
                if time.monotonic() > end:
                    raise RuntimeError("the kernel never became idle")
                time.sleep(0.25)
            driver.execute_script(
                "window.jupyterapp.commands.execute('notebook:run-all-cells')")
            report = folder / "shots.json"
            while not report.exists():
                if time.monotonic() > end:
                    raise RuntimeError("the notebook did not finish: "
                                       + (folder / "jupyterlab.log").read_text()[-2000:])
                time.sleep(0.5)
            time.sleep(20.0)  # the last keyframe shown; the streams (idle kernel) play
            cells = driver.find_elements(By.CSS_SELECTOR, ".jp-Notebook .jp-Cell")
            for name, cell_id in SHOTS.items():
                area = cells[ids.index(cell_id)].find_element(By.CSS_SELECTOR,
                                                              ".jp-Cell-outputArea")
                driver.execute_script("arguments[0].scrollIntoView({block: 'center'})", area)
                time.sleep(1.0)
                png = small_png(area.screenshot_as_png)
                (out / f"notebook_{name}.png").write_bytes(png)
                print(f"wrote {out / f'notebook_{name}.png'} ({len(png) // 1024} KB)")
            time.sleep(0.5)
            return json.loads(report.read_text())
        finally:
            if driver is not None:
                quit_browser(driver, profile)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    os.environ["PYTHONPATH"] = os.pathsep.join(
        filter(None, [str(ROOT / "src"), os.environ.get("PYTHONPATH")]))
    folder = Path(tempfile.mkdtemp(prefix="lodsprite-notebook-"))
    ids = notebook_copy(folder)
    report = run_in_lab(folder, ids, args.out)  # on failure, the folder stays (its log)
    shutil.rmtree(folder)
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
