"""The large-terrain reproduction's settings (:class:`LargeConfig`): its defaults, the
tests' :meth:`~LargeConfig.quick` and the long :meth:`~LargeConfig.full` sweep (GL-free;
read by the driver, :mod:`~lodsprite.experiments.large.run`, and its runs,
:mod:`~lodsprite.experiments.large.runs`)."""

from __future__ import annotations

from dataclasses import dataclass

from lodsprite.experiments.base import SplitSampled
from lodsprite.experiments.large.variants import VARIANTS

__all__ = ["LargeConfig"]


@dataclass(frozen=True)
class LargeConfig(SplitSampled):
    """The default, 4096² alone, took 13 min 57 s here (2026-12-03, every frontier run),
    within its 20 minutes.  16k² is in :meth:`full`, the long sweep: its level-0 reference
    draws level 0 window by window, 537 million triangles a chen1999 frame: 63-75 s a
    frame on llvmpipe, 51 s of it the draws and 5 s the chunks' decoding (one frame
    profiled, the machine shared), so that 20 sampled frames alone pass 20 minutes on a
    machine without a GPU.  LOD-sprite's setup over a 16k²
    store reads no level-0 chunk (first frame 7-11 s, was 188-468 s).  Timed runs at 1k²
    and 2k² are in :meth:`full` too (the default gives them the stand-in check alone);
    :meth:`quick` is the tests'."""

    sizes: tuple[int, ...] = (4096,)
    paths: tuple[str, ...] = ("chen1999", "flyover")
    frames: int = 120
    image: int = 256
    sse: float = 1.0
    key_sse: float = 0.5
    ref_sse: float = 0.25
    sample_every: int = 6     # 20 sampled frames: 10 to choose a row on, 10 to report
    eps: tuple[float, ...] = (1.0, 0.5)  # every LOD-sprite variant at each ε
    # tiled+cache and worker+tiled: --full
    variants: tuple[str, ...] = ("whole", "tiled", "worker")
    adaptive_sse: tuple[float, ...] = (0.5, 1.0, 2.0, 4.0)  # adaptive's frontier
    #: more whole-keyframe runs for LOD-sprite's frontier: (keyframe tolerance px, ε)
    key_sweep: tuple[tuple[float, float], ...] = ((2.0, 2.0), (4.0, 4.0))
    full_max: int = 4096      # full resolution timed up to this side
    validate_max: int = 4096  # the 0.25 px stand-in checked against level 0 up to this side
    validate_sizes: tuple[int, ...] = (1024, 2048)  # stores for that check alone, untimed
    patrol: bool = True       # the keyframe cache along the patrol path
    patrol_cache_mb: float = 64.0
    patrol_passes: int = 3    # the patrol flies this many times ``frames`` (its passes repeat)
    patrol_eps: float = 0.5   # ε of the patrol runs (at 1 px a 4k² patrol took one keyframe)
    huge: bool = False       # also 65536² (needs the disk and time it names)
    quick_512: bool = False  # the jacksboro runs on ``frames`` frames, not the whole path
    jacksboro: bool = True   # the 512² jacksboro comparison (tests leave it out)
    terrains: tuple[str, ...] = ()  # more terrains: stores, or sources to tile first
    vdp_seconds: float | None = None  # ColorVideoVDP over this long of each played run

    @classmethod
    def quick(cls) -> LargeConfig:
        return cls(sizes=(256, 512), frames=24, image=128, sample_every=6, quick_512=True,
                   eps=(1.0, 0.5), validate_sizes=(), patrol_passes=1,
                   adaptive_sse=(1.0, 4.0), key_sweep=((4.0, 4.0),))

    @classmethod
    def full(cls) -> LargeConfig:
        return cls(sizes=(1024, 2048, 4096, 16384), frames=230, image=512, sample_every=11,
                   eps=(1.0, 0.7, 0.5, 0.35, 0.25), validate_sizes=(),
                   variants=tuple(VARIANTS), adaptive_sse=(0.5, 1.0, 2.0, 4.0, 8.0, 16.0),
                   key_sweep=((1.0, 1.0), (2.0, 2.0), (4.0, 4.0)))

    @property
    def sample_frames(self) -> list[int]:
        return list(range(0, self.frames, self.sample_every))

