"""A cache of keyframes for moving back and forth in one region (Chen, Swan & Kaufman 1999,
§5: "a cache of keyframes" kept and reused when the viewer returns), GL-free.

The 1999 loop keeps one keyframe and replaces it as soon as its error (Eq. 2) reaches ε.
With a cache, every keyframe rendered is kept (its slot on the GPU, its viewpoint,
projection and ``C'``) until a byte budget forces one out; each frame the policy
(:class:`~lodsprite.sprite.policy.KeyframePolicy`) shows the cached keyframe with the
lowest error at the current view and renders a new one only when that lowest error is
still ``>= ε``.

Cost of the choice: one evaluation of the per-frame metric (Eq. 2 over the ``n x n``
square centres, about 0.2 ms in numpy for n = 16) per candidate, and a coverage test (the
centres in the current view must be in the keyframe's: a keyframe's own mask is computed
once and kept, :attr:`CachedKeyframe.in_view`).  Two prunings bound it:

* only the :data:`MAX_CANDIDATES` keyframes whose eyes are nearest the current eye are
  evaluated (the shown keyframe always among them): Eq. 2's angles grow with the eye's
  displacement from the keyframe's, so a far eye rarely wins, and the cost stays bounded
  whatever the budget;
* while the shown keyframe's error is under :data:`SWITCH_FRACTION` ε no other is
  evaluated (one metric evaluation, as without a cache): switching then could lower an
  error that is already small, but never saves a keyframe, which is due only at ε.

**Shown far from where it was taken** (:func:`far_error_px`).  Eq. 2 is the RMS of the
angles ``θ`` between each sample ``C`` and its reprojection ``C'`` over the samples in view;
a keyframe shown far from its eye ``v1`` also shows, where it did not see the surface, its
occluders' texels.  A sample is *hidden* in the keyframe when the ray from ``v1`` through
``C`` stops short of it (``|C' - v1| < (1 - HIDDEN_FRACTION) |C - v1|``: nearer terrain
occludes it; misses excepted, the metric floors them); seen from the current eye ``v2``
such a sample may be off by up to the eye's displacement across the key ray seen from
it, ``ρ = |(v2 - v1) × r| / |C - v2|`` radians (``r`` the key ray's unit direction: the
parallax between ``C`` and its occluder on that ray is at most ``ρ``).  The term is
``sqrt(mean(hidden · ρ²)) / β`` pixels over the samples in view, and
the cache compares and decides with ``sqrt(e_Eq2² + term²)``: a cached keyframe is shown
only while that stays under ε, and a new one is rendered when none passes.  Near its eye
(``ρ`` small) or where the keyframe saw every sample, the term vanishes and the choice is
Eq. 2's.  ``hidden`` needs ``C'`` at the key ray's first hit, as the view-dependent
proxy's metric casts it (:mod:`lodsprite.sprite.proxy_metric`); the uniform metric keeps
the hit nearest ``C`` (:mod:`lodsprite.sprite.raycast`), so there the term sees only
samples whose nearest hit is an occluder's.  :data:`HIDDEN_FRACTION` was chosen along
``reproduce large``'s patrol (docs: design/lodsprite.md, the keyframe cache): the largest
of those tried whose cached run stayed at or under the uncached one's RMSE and FLIP.
Cost per candidate, beside Eq. 2's: the samples in view (the test Eq. 2 makes) and a few
norms of the hidden ones; which are hidden is made once a keyframe.  Measured on this
project's 2-core machine (shared): 0.12 ms against Eq. 2's 0.12 ms at 256 samples,
0.46 ms against 1.05 ms at 7744.

Replacement, when the budget is full (never the keyframe shown):

* ``lru``: the keyframe least recently shown goes first;
* ``benefit``: the lowest benefit goes first, ``benefit = uses x cost_ms / age`` with
  ``uses`` the frames it was shown, ``cost_ms`` what rendering it cost and ``age`` the
  frames since it was last shown (+1): a keyframe that is often reused, dear to redo and
  recently useful stays.

**Tiled keyframes** (:class:`TileCache`; Qu, Wan, Qin & Kaufman 2000's tiled image, the
cache kept per screen tile).  Each screen tile ``t`` keeps up to ``K_t`` past renders in a
:class:`KeyframeCache` of its own (viewpoint, key projection, ``C'``, GPU slot), ``K_t``
what ``budget / T`` bytes hold at the tile's slot size
(:meth:`lodsprite.gl.sprite_tiles.TileSlots.tile_bytes`), replaced by the same policies,
never evicting the render a tile shows; so the cache's GPU bytes stay within the budget.
*Design* (the simpler one the issue allows, instead of an atlas the spriteframe shader
samples): the mosaic, the one keyframe target the tiled spriteframe samples, holds the
render each tile shows; every render is also copied into its slot, and a tile that
switches to a cached render gets it copied back into its rectangle (GPU-side copies,
:class:`~lodsprite.gl.sprite_tiles.TileSlots`); the spriteframe shader is unchanged.
*Choice per tile* (:meth:`TileCache.best`), each frame before the tiles to re-render are
selected: a tile whose error is at least :data:`SWITCH_FRACTION` ε evaluates its cached
renders (the :data:`MAX_CANDIDATES` nearest eyes, the shown one first) with
:func:`~lodsprite.sprite.tiled.render_error` and shows the lowest; a tile still at or over
ε after that is a candidate for re-rendering as without a cache
(:func:`~lodsprite.sprite.tiled.select_tiles`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from lodsprite.camera import Projection, Viewpoint
from lodsprite.errors import InputError

POLICIES = ("lru", "benefit")
DEFAULT_POLICY = "lru"
MAX_CANDIDATES = 8  # keyframes (nearest eyes) whose error is evaluated per frame
MIN_SLOTS = 2       # the keyframe shown and the one being rendered
SWITCH_FRACTION = 0.5  # of ε: below it the shown keyframe is kept without a search
HIDDEN_FRACTION = 0.1  # a key ray stopping this much short of its sample: hidden there


def far_error_px(metric, c_prime: np.ndarray, key_eye: np.ndarray, eye: np.ndarray,
                 view_proj: np.ndarray, pixel_angle_rad: float) -> float:
    """The term (px) of a keyframe shown far from where it was taken (module docstring):
    ``sqrt(mean(hidden · ρ²)) / β`` over the samples ``C`` of ``c_prime`` (its own, or
    ``metric``'s square centres) in the view ``view_proj (4, 4)``, ``ρ`` the part of
    ``eye - key_eye (3,)`` across the key ray over ``|C - eye|`` (metres over metres),
    ``hidden`` where the key ray through ``C`` stopped short of it; 0 when no sample is
    in view or hidden."""
    from lodsprite.sprite.metric import in_view
    from lodsprite.sprite.tiled import samples

    points, points_h = samples(metric, c_prime)
    vis = in_view(points_h, view_proj)
    count = int(vis.sum())
    if not count:
        return 0.0
    v1, v2 = np.asarray(key_eye, np.float64), np.asarray(eye, np.float64)
    hidden = _hidden(c_prime, points, v1) & vis
    if not hidden.any():
        return 0.0
    ray = points[hidden] - v1  # the key rays through the hidden samples in view
    side = np.linalg.norm(np.cross(v2 - v1, ray), axis=1) / np.linalg.norm(ray, axis=1)
    rho = side / np.maximum(np.linalg.norm(points[hidden] - v2, axis=1), 1e-6)
    return float(np.sqrt(np.sum(rho * rho) / count) / pixel_angle_rad)


def _hidden(c_prime: np.ndarray, points: np.ndarray, key_eye: np.ndarray) -> np.ndarray:
    """``(K,) bool``: the samples ``points`` whose key ray from ``key_eye`` stopped short
    (module docstring), misses excepted; made once a keyframe (kept on ``c_prime``)."""
    kept = getattr(c_prime, "hidden", None)
    if kept is not None and len(kept) == len(points):
        return kept
    cp = np.asarray(c_prime)
    hidden = np.linalg.norm(cp - key_eye, axis=1) < (1.0 - HIDDEN_FRACTION) * np.linalg.norm(
        points - key_eye, axis=1)
    missed = getattr(c_prime, "missed", None)
    if missed is not None and len(missed) == len(points):
        hidden &= ~missed
    try:
        c_prime.hidden = hidden
    except AttributeError:  # a plain array: made again each time
        pass
    return hidden


@dataclass
class CachedKeyframe:
    """One keyframe in the cache: ``index`` in the engine's keyframe log, its ``viewpoint``
    and frame ``projection`` (the renderer adds the guard band), ``c_prime`` (its
    Reprojection, ``(n*n, 3)`` metres), GPU ``slot``, ``last_use`` (frame number), ``uses``
    (frames shown), ``cost_ms`` (what rendering it cost) and ``born`` (frame number)."""

    index: int
    viewpoint: Viewpoint
    projection: Projection
    c_prime: np.ndarray
    slot: int
    last_use: int
    born: int
    uses: int = 0
    cost_ms: float = 0.0
    in_view: np.ndarray | None = None  # (n*n,) bool: square centres in its view, once made

    def benefit(self, now: int) -> float:
        """``uses x cost_ms / age`` with ``age = now - last_use + 1`` frames."""
        return self.uses * max(self.cost_ms, 1e-3) / (now - self.last_use + 1)


def capacity_for(budget_bytes: float, key_bytes: int) -> int:
    """Keyframes that fit ``budget_bytes`` at ``key_bytes`` each; raises
    :class:`InputError` below :data:`MIN_SLOTS`."""
    n = int(budget_bytes // key_bytes)
    if n < MIN_SLOTS:
        raise InputError(f"--cache-mb {budget_bytes / 2 ** 20:g} holds {n} keyframe(s) of "
                         f"{key_bytes / 2 ** 20:.2f} MB: give at least "
                         f"{MIN_SLOTS * key_bytes / 2 ** 20:.2f} MB (or 0: no cache)")
    return n


@dataclass
class KeyframeCache:
    """Keyframes kept within ``budget_bytes`` of GPU memory, ``key_bytes`` each, replaced
    by ``policy`` (:data:`POLICIES`).  Frame numbers are the caller's (one per frame)."""

    budget_bytes: float
    key_bytes: int
    policy: str = DEFAULT_POLICY
    entries: list[CachedKeyframe] = field(default_factory=list)
    shown: CachedKeyframe | None = None
    max_resident: int = 0
    evicted: int = 0

    def __post_init__(self) -> None:
        if self.policy not in POLICIES:
            raise InputError(f"unknown cache policy {self.policy!r}: use "
                             f"{' or '.join(POLICIES)}")
        self.capacity = capacity_for(self.budget_bytes, self.key_bytes)

    @property
    def resident_bytes(self) -> int:
        """GPU bytes the cached keyframes hold."""
        return len(self.entries) * self.key_bytes

    def candidates(self, eye: np.ndarray) -> list[CachedKeyframe]:
        """The keyframes worth evaluating at ``eye``: the :data:`MAX_CANDIDATES` nearest
        eyes, the shown one first (ties keep it)."""
        others = [e for e in self.entries if e is not self.shown]
        if len(others) >= MAX_CANDIDATES:
            dist = [float(np.sum((e.viewpoint.o - eye) ** 2)) for e in others]
            order = np.argsort(dist, kind="stable")[:MAX_CANDIDATES - 1]
            others = [others[i] for i in order]
        return ([self.shown] if self.shown is not None else []) + others

    def victim(self, now: int) -> CachedKeyframe:
        """The keyframe to replace: never the shown one (lowest benefit or least recent)."""
        pool = [e for e in self.entries if e is not self.shown]
        if self.policy == "lru":
            return min(pool, key=lambda e: (e.last_use, e.born))
        return min(pool, key=lambda e: (e.benefit(now), e.last_use, e.born))

    def insert(self, index: int, viewpoint: Viewpoint, projection: Projection,
               c_prime: np.ndarray, now: int) -> CachedKeyframe:
        """Keep a new keyframe (shown from now): a free slot, or the victim's; returns it."""
        if len(self.entries) < self.capacity:
            slot = len(self.entries)
        else:
            old = self.victim(now)
            self.entries.remove(old)
            self.evicted += 1
            slot = old.slot
        entry = CachedKeyframe(index, viewpoint, projection, c_prime, slot, now, now)
        self.entries.append(entry)
        self.max_resident = max(self.max_resident, len(self.entries))
        self.use(entry, now)
        return entry

    def use(self, entry: CachedKeyframe, now: int) -> None:
        """``entry`` is shown in frame ``now``."""
        entry.uses += 1
        entry.last_use = now
        self.shown = entry


class TileCache:
    """Per tile, a :class:`KeyframeCache` of its renders within ``budget_bytes / T``
    bytes, ``tile_bytes[t]`` each (at least two per tile: the shown one and a new one;
    :class:`~lodsprite.errors.InputError` otherwise), replaced by ``policy``."""

    def __init__(self, budget_bytes: float, tile_bytes: Sequence[int], policy: str) -> None:
        t = len(tile_bytes)
        self.budget_bytes = float(budget_bytes)
        self.caches = [KeyframeCache(budget_bytes / t, int(b), policy) for b in tile_bytes]
        self.max_resident = 0

    @property
    def resident_bytes(self) -> int:
        """GPU bytes the cached renders hold, all tiles."""
        return sum(c.resident_bytes for c in self.caches)

    @property
    def resident(self) -> int:
        return sum(len(c.entries) for c in self.caches)

    def insert(self, tile: int, update: int, viewpoint: Viewpoint, key_projection: Projection,
               c_prime: np.ndarray, now: int) -> CachedKeyframe:
        """Keep tile ``tile``'s new render (update ``update`` of the engine, seen through
        ``key_projection``, the widened one), shown from now; returns its entry (its
        ``slot`` is where the GPU copy goes)."""
        entry = self.caches[tile].insert(update, viewpoint, key_projection, c_prime, now)
        self.max_resident = max(self.max_resident, self.resident)
        return entry

    def best(self, tile: int, eye: np.ndarray, error_of: Callable[[CachedKeyframe], float],
             now: int) -> tuple[CachedKeyframe | None, float]:
        """``(entry, error px)``: the render of ``tile`` with the lowest ``error_of`` among
        the candidates at ``eye`` (the shown one first, kept on ties), marked shown in
        frame ``now``; ``(None, inf)`` when the tile has none."""
        cache = self.caches[tile]
        cands = cache.candidates(np.asarray(eye, np.float64))
        if not cands:
            return None, float("inf")
        errs = [error_of(e) for e in cands]
        k = int(np.argmin(errs))
        cache.use(cands[k], now)
        return cands[k], float(errs[k])

    def keep(self, tile: int, now: int) -> None:
        """The tile's shown render is shown in frame ``now`` too (recency and uses)."""
        cache = self.caches[tile]
        if cache.shown is not None:
            cache.use(cache.shown, now)
