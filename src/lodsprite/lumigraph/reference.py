"""The ground truth of a lumigraph's frames: the object it was captured from, drawn
directly from the same eye (:class:`ObjectReference`), a code path independent of the
reconstruction it judges (no node image, no proxy).  Capture keeps the object beside the
nodes (``object.npz``, :data:`OBJECT_FILE`)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from lodsprite.camera import Viewpoint
from lodsprite.errors import InputError
from lodsprite.lumigraph.capture import ColorMesh

OBJECT_FILE = "object.npz"


def read_object(folder: Path) -> ColorMesh | None:
    """The object a lumigraph was captured from (its folder's ``object.npz``), or None."""
    path = Path(folder) / OBJECT_FILE
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as z:
        return ColorMesh(z["vertices"].astype(np.float64), z["faces"].astype(np.int32),
                         z["colors"].astype(np.float64), z["normals"].astype(np.float64))


class ObjectReference:
    """The ground truth of a lumigraph frame: the object drawn directly from the same eye
    (a viewpoint in the lumigraph's world), ``(h, w, 3) uint8``."""

    def __init__(self, gl, mesh: ColorMesh, size: tuple[int, int], projection) -> None:
        from lodsprite.gl.lumigraph import ColorMeshDrawer
        from lodsprite.gl.target import RenderTarget

        self.truth = ColorMeshDrawer(gl, mesh.vertices, mesh.faces, mesh.colors,
                                       mesh.normals)
        self.target = RenderTarget(gl, *size)
        self.projection = projection

    def __call__(self, viewpoint: Viewpoint) -> np.ndarray:
        self.truth.render(self.projection @ viewpoint.view_matrix(), self.target.fbo)
        return self.target.read_color()

    def release(self) -> None:
        self.target.release()
        self.truth.release()


@contextmanager
def object_reference(gl, folder: Path, size: tuple[int, int], projection
                     ) -> Iterator[ObjectReference]:
    """The :class:`ObjectReference` of the lumigraph in ``folder`` (its ``object.npz``),
    released on leaving; a folder without the object is an :class:`InputError`."""
    mesh = read_object(Path(folder))
    if mesh is None:
        raise InputError(f"{folder} holds no {OBJECT_FILE}: no ground truth to compare with")
    ref = ObjectReference(gl, mesh, size, projection)
    try:
        yield ref
    finally:
        ref.release()


__all__ = ["OBJECT_FILE", "ObjectReference", "object_reference", "read_object"]
