"""examples/notebook.ipynb executed headless, as ``jupyter nbconvert --execute`` runs it:
a fresh kernel (nbclient), no front end attached.  Every cell runs to its end without a
browser (none waits for one beyond its deadline), each scene's widget is the value of its
cell, the stream widgets' kernel-side frames show their scenes, the bad-input cell fails
with one typed line, and the closing cell runs clean."""

import base64
import os
from io import BytesIO
from pathlib import Path

import numpy as np
import pytest

from conftest import needs

pytestmark = needs("anywidget", "jupyter_rfb", "nbclient", "nbformat",
                   reason="the notebook and test extras")

ROOT = Path(__file__).resolve().parents[2]
NOTEBOOK = ROOT / "examples" / "notebook.ipynb"
VIEW = "application/vnd.jupyter.widget-view+json"
TIMEOUT_S = 120  # a cell's deadline; the whole notebook runs in seconds


@pytest.fixture(scope="module")
def executed(tmp_path_factory):
    """The notebook after its run: cells by id."""
    import nbclient
    import nbformat

    nb = nbformat.read(NOTEBOOK, as_version=4)
    home = tmp_path_factory.mktemp("kernel")
    env = {**os.environ, "IPYTHONDIR": str(home / ".ipython"),
           "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT / "src"),
                                                       os.environ.get("PYTHONPATH")]))}
    client = nbclient.NotebookClient(nb, timeout=TIMEOUT_S, kernel_name="python3",
                                     resources={"metadata": {"path": str(NOTEBOOK.parent)}})
    client.execute(env=env)  # raises CellExecutionError on an unexpected error
    return {cell.id: cell for cell in nb.cells}


def outputs(cell, kind=None):
    return [o for o in cell.outputs if kind is None or o.output_type == kind]


def test_the_stored_notebook_has_no_outputs():
    import nbformat

    nb = nbformat.read(NOTEBOOK, as_version=4)
    nbformat.validate(nb)
    assert all(not c.get("outputs") for c in nb.cells if c.cell_type == "code")


def test_every_scene_is_its_cell_widget_and_the_streams_show_their_scene(executed):
    kinds = {"terrain": "SpriteWidget", "battle": "StreamWidget", "light": "StreamWidget"}
    models = set()
    for cell_id, kind in kinds.items():
        (value,) = outputs(executed[cell_id], "execute_result")
        assert kind in value.data["text/plain"], value.data
        models.add(value.data[VIEW]["model_id"])
    assert len(models) == 3
    for cell_id in ("battle-picture", "light-picture"):
        (shown,) = [o for o in outputs(executed[cell_id], "execute_result")
                    if "image/png" in o.data]
        from PIL import Image

        image = np.asarray(Image.open(BytesIO(base64.b64decode(shown.data["image/png"])))
                           .convert("RGB"))
        assert image.shape == (320, 480, 3)
        colours = len(np.unique(image.reshape(-1, 3), axis=0))
        assert colours > 50, f"{cell_id}: a blank frame ({colours} colours)"
        background = np.all(image == image[0, 0], axis=-1).mean()
        assert background < 0.95, f"{cell_id}: the scene is not in view"


def test_without_a_front_end_the_cells_say_so_and_bad_input_is_one_line(executed):
    text = "".join(o.get("text", "") for o in outputs(executed["played"], "stream"))
    assert "No front end shows the widget" in text
    (error,) = outputs(executed["error"], "error")
    assert error.ename == "InputError" and "nowhere" in error.evalue
    assert len(error.traceback) == 1 and "\n" not in error.traceback[0]
    assert not outputs(executed["close"], "error")
