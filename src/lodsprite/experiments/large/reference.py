"""The reference images of ``reproduce large`` and a validation of the adaptive renderer
at 0.25 px against it.

The reference is level 0's own samples at full resolution, the one reference of every
quality figure (:class:`lodsprite.gl.reference.LevelZeroReference`: a code path
independent of the adaptive renderer, level 0 whole up to 4097 samples a side, beyond
that the view's footprint, tile by tile if need be), at every side and every sampled
frame: never the renderer under test.  It is coloured by the one shading of stores
(``terrain_shade``, normals per pixel from the heights), as every timed run over a store
is (``--shading auto``).

With ``validate`` the adaptive renderer at ``ref_sse`` (0.25 px), streamed until
complete, is compared with it: ``stand_in_rmse`` (grey levels) and ``stand_in_flip``, a
validation figure only (how close the adaptive renderer gets at a tiny tolerance), never
a reference.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

Images = dict[int, np.ndarray]


def errors(a: Images, b: Images) -> tuple[float, float]:
    """Mean RMSE (grey levels) and mean FLIP of the images ``a`` against ``b`` (frame
    index -> ``(h, w, 3) uint8``, the frames of ``a``)."""
    from lodsprite.metrics import flip, rmse

    return (float(np.mean([rmse(a[i], b[i]) for i in a])),
            float(np.mean([flip(a[i], b[i]) for i in a])))


def saved_frames(folder: Path, keep: list[int]) -> Images:
    """The PNG frames ``keep`` a run saved in ``folder/frames``."""
    from lodsprite.api import read_image

    return {i: read_image(Path(folder) / "frames" / f"frame_{i:05d}.png") for i in keep}


def adaptive_images(store: Path, path, image: int, keep: list[int], sse: float) -> Images:
    """The settled adaptive frames at ``sse`` px of the viewpoints ``keep`` of ``path``
    over ``store``, ``image`` pixels a side, coloured by the heights shading."""
    from lodsprite.gl.context import GLContext
    from lodsprite.gl.target import RenderTarget
    from lodsprite.techniques.adaptive_terrain import AdaptiveTerrain
    from lodsprite.terrain.store import TerrainStore

    out = {}
    with GLContext() as gl:
        t = RenderTarget(gl, image, image)
        a = AdaptiveTerrain(gl, TerrainStore(store), t, path.fov_y_deg, sse,
                            gpu_mb=256.0, host_mb=512.0, upload_budget=16, color=None)
        try:
            for i in keep:
                a.settle(path.viewpoints[i])
                out[i] = t.read_color()
        finally:
            a.release()
            t.release()
    return out


def level_zero_images(store: Path, path, image: int, keep: list[int]) -> tuple[Images, str]:
    """Level 0's own samples at the viewpoints ``keep`` and how they were made."""
    from lodsprite.gl.context import GLContext
    from lodsprite.gl.reference import LevelZeroReference
    from lodsprite.terrain.store import TerrainStore

    out: Images = {}
    with GLContext() as gl:
        ref = LevelZeroReference(gl, TerrainStore(store), (image, image), path.fov_y_deg, "auto")
        try:
            for i in keep:
                out[i] = ref.image(path.viewpoints[i])
            how = ref.describe()
        finally:
            ref.release()
    return out, how


def reference_images(store: Path, path, image: int, keep: list[int],
                     ref_sse: float, validate: bool) -> tuple[Images, dict]:
    """Level 0's image of each sampled frame ``keep`` and how it was made (``level0``,
    ``level0_frames``).  With ``validate`` the adaptive renderer at ``ref_sse`` px,
    settled, is compared with it: ``stand_in`` (what it was), ``stand_in_rmse``,
    ``stand_in_flip`` (means over ``keep``)."""
    level0, how = level_zero_images(store, path, image, keep)
    desc: dict = {"level0": how, "level0_frames": len(keep)}
    if validate:
        check = adaptive_images(store, path, image, keep, ref_sse)
        desc["stand_in"] = f"adaptive at {ref_sse:g} px, settled (validation only)"
        desc["stand_in_rmse"], desc["stand_in_flip"] = errors(check, level0)
    return level0, desc
