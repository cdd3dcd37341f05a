"""The widget in a real notebook: JupyterLab 4 started by the test, headless Chromium
opens a notebook and runs its cells; the widget plays chen1999 in the cell's output and
the kernel reads back what the browser measured (``w.stats``) and showed
(``await w.screenshot()``): a terrain store draped with an orthophoto, whose colours the
screenshot shows."""

import json
import time
from io import BytesIO

import numpy as np
import pytest
from lab_fixtures import jupyterlab

from browsers import HAVE_CHROMIUM, NO_CHROMIUM, quit_browser, start_browser
from conftest import needs
from draped import EAST_RGB, WEST_RGB, flat_dem, write_draped

pytestmark = [needs("anywidget", "jupyterlab", "selenium.webdriver",
                    reason="the notebook and test extras"),
              pytest.mark.skipif(not HAVE_CHROMIUM, reason=NO_CHROMIUM)]
DEADLINE_S = 90.0
SIZE = 128
CELLS = [
    "import lodsprite\n"
    f"w = lodsprite.widget('draped.zarr', grid=64, lod=8, size=({SIZE}, {SIZE}), "
    "path='chen1999', frames=48)\nw",
    "import json\nframes = await w.played(timeout=80)\n"
    "png = await w.screenshot()\nopen('shot.png', 'wb').write(png)\n"
    "json.dump({**w.stats, 'played': frames}, open('stats.json', 'w'))",
    "w.close()\nopen('closed', 'w').write(str(w._core.pool.local_processes()[0].is_alive()))",
]


def wait_file(path, deadline_s: float, log):
    end = time.monotonic() + deadline_s
    while not path.exists():
        assert time.monotonic() < end, f"no {path.name} in {deadline_s:g} s; {log()}"
        time.sleep(0.25)
    time.sleep(0.2)  # written by one call: let it close
    return path


def test_the_widget_plays_in_jupyterlab_and_the_kernel_reads_its_stats(tmp_path):
    import nbformat
    from PIL import Image

    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_code_cell(c) for c in CELLS]
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3",
                                 "language": "python"}
    nbformat.write(nb, tmp_path / "fly.ipynb")
    write_draped(flat_dem(tmp_path / "dem.tif"), tmp_path / "draped.zarr")
    driver = profile = None
    with jupyterlab(tmp_path, DEADLINE_S) as (base, token):
        try:
            driver, profile = start_browser(DEADLINE_S, (1000, 800))
            driver.get(f"{base}/lab/tree/fly.ipynb?token={token}")

            def lab_state():
                return driver.execute_script(
                    "const w = window.jupyterapp && window.jupyterapp.shell.currentWidget;"
                    "const k = w && w.sessionContext && w.sessionContext.session"
                    " && w.sessionContext.session.kernel;"
                    "return k ? k.status : 'no kernel';")

            end = time.monotonic() + DEADLINE_S
            while lab_state() != "idle":
                assert time.monotonic() < end, f"the kernel never became idle: {lab_state()}"
                time.sleep(0.25)
            driver.execute_script(
                "window.jupyterapp.commands.execute('notebook:run-all-cells')")
            log = lambda: (tmp_path / "jupyterlab.log").read_text()[-1500:]  # noqa: E731
            stats = json.loads(wait_file(tmp_path / "stats.json", DEADLINE_S, log).read_text())
            closed = wait_file(tmp_path / "closed", DEADLINE_S, log).read_text()
        finally:
            if driver is not None:
                quit_browser(driver, profile)
    assert stats["played"] >= 48, stats
    # read at once after played(): the figures as the path ended, not a status before it
    assert stats["frames"] >= stats["played"], stats
    assert stats["keyframes"] >= 1, stats
    assert stats["median_ms"] is not None and stats["error_px_mean"] is not None, stats
    shot = np.asarray(Image.open(BytesIO((tmp_path / "shot.png").read_bytes())).convert("RGB"))
    assert shot.shape == (SIZE, SIZE, 3)
    sky = np.all(np.abs(shot.astype(int) - [158, 189, 219]) <= 2, axis=-1)
    assert sky.mean() < 0.9, "the screenshot shows no terrain"
    west = np.all(np.abs(shot.astype(int) - WEST_RGB) <= 12, axis=-1)
    east = np.all(np.abs(shot.astype(int) - EAST_RGB) <= 12, axis=-1)
    assert (west | east | sky).mean() > 0.95, "the widget does not show the imagery"
    assert (west | east).mean() > 0.05
    assert closed == "False", "close() left the renderer process running"
