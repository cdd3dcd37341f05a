"""The reference images of ``reproduce large`` and the check of the adaptive renderer's
0.25 px stand-in against it.

The reference is full resolution, level 0's own samples: the measure part's
:class:`lodsprite.gl.reference.LevelZeroReference` (a code path independent of the
adaptive renderer: whole up to its cap, a level-0 window cropped to the frustum's
footprint beyond; ``image()`` None where even that is over its cap).  A frame it cannot
draw takes the stand-in: the adaptive renderer at ``ref_sse`` (0.25 px), streamed until
complete.  Both are coloured by the one shading of stores (``terrain_shade``, normals per
pixel from the heights), as every timed run over a store is (``--shading auto``).

:func:`stand_in_check` gives the stand-in's RMSE (grey levels) and FLIP against level 0
at every side up to ``validate_max`` (1k²–4k²).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

FULL_MAX = 4096
FULL_SSE = 1e-6  # px: every node refined to level 0 (the fallback's full resolution)
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


def adaptive_images(store: Path, scene, path, image: int, keep: list[int],
                    sse: float) -> Images:
    """The settled adaptive frames at ``sse`` px (:data:`FULL_SSE`: every node at level
    0) of the viewpoints ``keep`` of ``path`` over ``store``, ``image`` pixels a side,
    coloured by the heights shading (``scene`` is unused: kept for the callers)."""
    from lodsprite.gl.context import GLContext
    from lodsprite.gl.target import RenderTarget
    from lodsprite.techniques.adaptive_terrain import AdaptiveTerrain
    from lodsprite.terrain.store import TerrainStore

    full = sse <= FULL_SSE
    out = {}
    with GLContext() as gl:
        t = RenderTarget(gl, image, image)
        a = AdaptiveTerrain(gl, TerrainStore(store), t, path.fov_y_deg, sse,
                            gpu_mb=1024.0 if full else 256.0, host_mb=1024.0 if full else 512.0,
                            upload_budget=4096 if full else 16, color=None)
        try:
            for i in keep:
                a.settle(path.viewpoints[i])
                out[i] = t.read_color()
        finally:
            a.release()
            t.release()
    return out


def level_zero_images(store: Path, scene, path, image: int, keep: list[int]
                      ) -> tuple[dict[int, np.ndarray | None], str]:
    """Level 0's own samples at the viewpoints ``keep`` (None for a frame the reference
    cannot draw) and how they were made."""
    from lodsprite.gl.context import GLContext
    from lodsprite.gl.reference import LevelZeroReference
    from lodsprite.terrain.store import TerrainStore

    out: dict[int, np.ndarray | None] = {}
    with GLContext() as gl:
        ref = LevelZeroReference(gl, TerrainStore(store), (image, image), path.fov_y_deg, "auto")
        try:
            for i in keep:
                out[i] = ref.image(path.viewpoints[i])
            how = str(ref.describe())
        finally:
            getattr(ref, "release", lambda: None)()
    return out, how


def reference_images(store: Path, scene, path, image: int, keep: list[int],
                     ref_sse: float, validate: bool) -> tuple[Images, dict]:
    """The reference of each sampled frame and how it was made: level 0 where it can be
    drawn, else the ``ref_sse`` stand-in.  With ``validate`` (sides 1k²–4k²) the
    stand-in is rendered too and compared with level 0: ``stand_in_rmse``,
    ``stand_in_flip`` over the frames both exist."""
    level0, how = level_zero_images(store, scene, path, image, keep)
    missing = [i for i in keep if level0[i] is None]
    stand_in: Images = {}
    if missing or validate:
        stand_in = adaptive_images(store, scene, path, image,
                                   keep if validate else missing, ref_sse)
    ref = {i: level0[i] if level0[i] is not None else stand_in[i] for i in keep}
    desc: dict = {"level0": how, "level0_frames": len(keep) - len(missing),
                  "stand_in": f"adaptive at {ref_sse:g} px, settled",
                  "stand_in_frames": len(missing)}
    both = {i: stand_in[i] for i in keep if i in stand_in and level0[i] is not None}
    if validate and both:
        desc["stand_in_rmse"], desc["stand_in_flip"] = errors(
            both, {i: level0[i] for i in both})
    return ref, desc
