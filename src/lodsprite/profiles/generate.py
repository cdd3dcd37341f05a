"""LOD error profile generation (Scoggins et al. 2000 §3.3, §4.1 and Figure 3).

For every view direction ``(phi, theta)``: render the full model and each LOD at the
reference distance ``z0`` with a directional light and flat shading, take the power
spectra of the Hanning-windowed images, and evaluate Eq. 7 and Eq. 16 at the
importance-sampled distances (see :mod:`lodsprite.profiles.spectra`).

Where the paper set ``z0`` and the magnified view by hand, we derive them from the full
model's bounding sphere (centre ``c``, radius ``R``): ``z0 = z0_diameters * 2R`` (9
diameters, the paper's sphere choice) and a field of view ``2 asin(R / z0)`` whose cone
just contains the sphere, so the object fills the ``M x M`` image without clipping
(§3.1).  Views: ``theta`` is the elevation above the object's xy-plane (0 = level,
90 = from +z), ``phi`` the azimuth from +x; the eye is ``c + z0 (cos theta cos phi,
cos theta sin phi, sin theta)``.  (The paper calls theta a zenith angle, but its Fig. 6a
shows views at theta = 0 that differ with phi, which a view from the pole could not.)

Views are independent, so they run in parallel: local worker processes by default
(each with its own headless GL context), or the workers of a Dask distributed cluster
when a scheduler address is given.  Dask is optional (the ``cluster`` extra:
``pip install 'lodsprite[cluster]'``); only a scheduler address needs it.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from multiprocessing import get_context

import numpy as np

from lodsprite.camera import Viewpoint, perspective
from lodsprite.cluster import connect, require_dask
from lodsprite.errors import InputError
from lodsprite.profiles.spectra import CSF_NAME, F_MIN, distances, lod_errors, power_spectra
from lodsprite.profiles.table import ProfileTable
from lodsprite.progress import Progress

# Paper §4.3: z1 = z0 + 50 km with z0 = 135 km, i.e. each distance 1.37 times the last.
DEFAULT_Z_RATIO = 185.0 / 135.0
DEFAULT_LIGHT = (0.35, 0.25, 0.9)  # towards the light, object space (sun high in the south-east)

@dataclass(frozen=True)
class ProfileSettings:
    """What a profile is computed with; every field is stored in the table's metadata."""

    image_size: int = 512
    phi_step_deg: float = 30.0
    theta_step_deg: float = 15.0
    theta_max_deg: float = 90.0
    z0_diameters: float = 9.0
    z_ratio: float = DEFAULT_Z_RATIO
    f_min: int = F_MIN
    light: tuple[float, float, float] = DEFAULT_LIGHT
    ambient: float = 0.15
    samples: int = 4

    def __post_init__(self) -> None:
        if self.image_size < 4 * self.f_min or self.image_size > 4096:
            raise InputError(f"image size must be in {4 * self.f_min}..4096 pixels")
        if not (0 < self.phi_step_deg <= 360 and 0 < self.theta_step_deg <= 90):
            raise InputError("view steps must be in (0, 360] and (0, 90] degrees")
        if not self.z_ratio > 1.0:
            raise InputError("z ratio z1/z0 must be greater than 1")
        if not self.z0_diameters > 1.0:
            raise InputError("z0 must be more than one bounding diameter away")

    def phis(self) -> np.ndarray:
        return np.arange(0.0, 360.0 - 1e-9, self.phi_step_deg)

    def thetas(self) -> np.ndarray:
        return np.arange(0.0, self.theta_max_deg + 1e-9, self.theta_step_deg)


@dataclass(frozen=True)
class ViewSetup:
    """Geometry shared by every view of one profile (object units, degrees)."""

    centre: tuple[float, float, float]
    radius: float
    z0: float
    fov_deg: float
    z: tuple[float, ...]
    settings: ProfileSettings = field(default_factory=ProfileSettings)

    @classmethod
    def for_sphere(cls, centre: np.ndarray, radius: float,
                   settings: ProfileSettings) -> ViewSetup:
        if not radius > 0:
            raise InputError("the model has no extent (bounding radius 0)")
        z0 = settings.z0_diameters * 2.0 * radius
        fov = 2.0 * math.degrees(math.asin(radius / z0))
        z = distances(z0, z0 * settings.z_ratio, settings.image_size, settings.f_min)
        return cls(tuple(float(c) for c in centre), float(radius), z0, fov,
                   tuple(float(v) for v in z), settings)


def view_camera(setup: ViewSetup, phi_deg: float, theta_deg: float) -> np.ndarray:
    """World(=object)-to-clip matrix ``(4, 4)`` of the profile view ``(phi, theta)``."""
    p, t = math.radians(phi_deg), math.radians(theta_deg)
    d = np.array([math.cos(t) * math.cos(p), math.cos(t) * math.sin(p), math.sin(t)])
    up = np.array([-math.sin(t) * math.cos(p), -math.sin(t) * math.sin(p), math.cos(t)])
    centre = np.asarray(setup.centre)
    vp = Viewpoint(np.cross(up, d), up, d, centre + setup.z0 * d)
    r = setup.radius * 1.01
    proj = perspective(setup.fov_deg, 1.0, setup.z0 - r, setup.z0 + r)
    return proj @ vp.view_matrix()


# --- one view, in whichever process or thread runs it --------------------------------------

_CACHE: dict[tuple, tuple] = {}
_CACHE_LOCK = threading.Lock()


def _renderer(key: str, levels: Sequence[tuple[np.ndarray, np.ndarray]], image_size: int,
              samples: int) -> tuple:
    """This thread's (GLContext, MeshDrawer, MeshSet) for a chain, created once."""
    from lodsprite.gl.context import GLContext
    from lodsprite.gl.mesh import MeshDrawer, MeshSet

    ckey = (key, image_size, samples, threading.get_ident())
    with _CACHE_LOCK:
        if ckey not in _CACHE:
            for old in [k for k in _CACHE if k[3] == ckey[3]]:  # one chain per thread
                _release(_CACHE.pop(old))
            ctx = GLContext()
            with ctx.mgl:
                _CACHE[ckey] = (ctx, MeshDrawer(ctx, image_size, image_size, samples, 1),
                                MeshSet(ctx, levels))
        return _CACHE[ckey]


def _release(entry: tuple) -> None:
    ctx, renderer, meshes = entry
    with ctx.mgl:
        renderer.forget(meshes)
        meshes.release()
        renderer.release()
    ctx.release()


def release_cached() -> None:
    """Release the GL objects that in-process profile generation keeps for reuse."""
    from lodsprite.gl.context import keep_current

    with _CACHE_LOCK, keep_current():
        for key in list(_CACHE):
            _release(_CACHE.pop(key))


def view_errors(key: str, levels: Sequence[tuple[np.ndarray, np.ndarray]], setup: ViewSetup,
                phi_deg: float, theta_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 7 and Eq. 16 errors ``(L, nz)`` each for one view; ``levels`` coarsest first,
    the last one the full model."""
    s = setup.settings
    ctx, renderer, meshes = _renderer(key, levels, s.image_size, s.samples)
    view_proj = view_camera(setup, phi_deg, theta_deg)
    images = np.zeros((len(levels), s.image_size, s.image_size), dtype=np.float32)
    with ctx.mgl:
        for level in range(len(levels)):
            renderer.render(meshes, np.array([level]), np.eye(4)[None], view_proj, s.light,
                            ambient=s.ambient)
            images[level] = renderer.read_luminance()
        ctx.check_error("profile view")
    spectra = power_spectra(images)
    z = np.asarray(setup.z)
    plain = lod_errors(spectra[-1], spectra, z, setup.z0, setup.fov_deg, weighted=False)
    weighted = lod_errors(spectra[-1], spectra, z, setup.z0, setup.fov_deg, weighted=True)
    return plain, weighted


# --- local processes ------------------------------------------------------------------------

_WORKER: dict = {}


def _init_worker(key: str, levels: list, setup: ViewSetup) -> None:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    _WORKER.update(key=key, levels=levels, setup=setup)


def _worker_view(view: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    return view_errors(_WORKER["key"], _WORKER["levels"], _WORKER["setup"], *view)


def _dask_view(payload: tuple, view: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    key, levels, setup = payload
    return view_errors(key, levels, setup, *view)


def _run_views(key: str, levels: list, setup: ViewSetup, views: list[tuple[float, float]],
               workers: int, scheduler: str | None, progress: Progress | None) -> list:
    results: list = [None] * len(views)

    def done(n: int) -> None:
        if progress is not None:
            progress(n, len(views))

    if scheduler:
        dask_distributed = require_dask()
        with connect(scheduler) as client:
            payload = client.scatter((key, levels, setup), broadcast=True)
            futures = client.map(_dask_view, [payload] * len(views), views, pure=False)
            index = {f.key: i for i, f in enumerate(futures)}
            for n, fut in enumerate(dask_distributed.as_completed(futures), 1):
                results[index[fut.key]] = fut.result()
                done(n)
        return results
    if workers <= 1:
        from lodsprite.gl.context import keep_current

        with keep_current():  # the caller's context stays current
            for n, view in enumerate(views, 1):
                results[n - 1] = view_errors(key, levels, setup, *view)
                done(n)
        return results
    with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn"),
                             initializer=_init_worker, initargs=(key, levels, setup)) as pool:
        futures = {pool.submit(_worker_view, view): i for i, view in enumerate(views)}
        try:
            for n, fut in enumerate(as_completed(futures), 1):
                results[futures[fut]] = fut.result()
                done(n)
        except BaseException:
            pool.shutdown(wait=True, cancel_futures=True)  # report a failure at once
            raise
    return results


def default_workers() -> int:
    """Worker processes used when none are asked for: the cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def generate_profile(chain, settings: ProfileSettings | None = None, workers: int | None = None,
                     scheduler: str | None = None, progress: Progress | None = None,
                     geometric_error: np.ndarray | None = None) -> ProfileTable:
    """Compute the LOD error table of ``chain`` (a :class:`~lodsprite.profiles.chain.LodChain`,
    levels coarsest first, the last the full model).

    ``workers``: local processes (default: one per usable core; 1 runs in this process).
    ``scheduler``: a Dask scheduler address (``tcp://host:8786``); its workers run the views.
    ``progress(done, total)`` is called as views complete.  ``geometric_error (L,)`` is
    stored for screen-space-error selection (computed from the chain when omitted).
    """
    from lodsprite import __version__
    from lodsprite.profiles.chain import geometric_errors

    if scheduler:
        require_dask()  # before any work
    settings = settings or ProfileSettings()
    centre, radius = chain.full.bounding_sphere()
    setup = ViewSetup.for_sphere(centre, radius, settings)
    levels = [(m.vertices, m.faces) for m in chain.levels]
    key = "/".join(chain.digests)
    phis, thetas = settings.phis(), settings.thetas()
    views = [(float(p), float(t)) for p in phis for t in thetas]
    workers = min(default_workers() if workers is None else max(1, int(workers)), len(views))
    start = time.perf_counter()
    results = _run_views(key, levels, setup, views, workers, scheduler, progress)
    seconds = time.perf_counter() - start
    shape = (len(levels), len(phis), len(thetas), len(setup.z))
    error, error_csf = np.zeros(shape), np.zeros(shape)
    for n, (plain, weighted) in enumerate(results):
        i, j = divmod(n, len(thetas))
        error[:, i, j], error_csf[:, i, j] = plain, weighted
    if geometric_error is None:
        geometric_error = geometric_errors(chain)
    meta = {
        "model": chain.name, "digests": list(chain.digests), "fov_deg": setup.fov_deg,
        "image_size": settings.image_size, "z0": setup.z0, "z_ratio": settings.z_ratio,
        "f_min": settings.f_min, "light": list(settings.light), "ambient": settings.ambient,
        "samples": settings.samples, "centre": list(setup.centre), "radius": setup.radius,
        "csf": CSF_NAME, "seconds": seconds, "workers": "dask" if scheduler else workers,
        "settings": asdict(settings), "lodsprite": __version__,
    }
    return ProfileTable(error, error_csf, phis, thetas, np.asarray(setup.z),
                        np.asarray(chain.faces), np.asarray(geometric_error), meta)
