"""What an experiment is: options in, a run that writes its outputs, a summary table out.

An :class:`Experiment` is one reproduction: its name, its default output folder
(``out/NAME``), how it reads the shared :class:`Options` (its defaults and checks), the
run (results, ``results.json``, plots and ``report.md``) and the :class:`Summary` the
command line prints after it.  The registry (:func:`lodsprite.experiments.get`) maps a
name to one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lodsprite.progress import Progress, StageProgress


@dataclass(frozen=True)
class Options:
    """The ``reproduce`` command's options; each experiment reads the ones it uses.

    ``size`` is the square image side in pixels; ``max_error`` None is the client's
    default bound (swan2002); ``huge`` adds a 65536² store (large); ``full`` is the long
    sweep (large); ``path`` the camera path (timecritical); ``vdp`` seconds of each
    played run judged by ColorVideoVDP (timecritical, large); ``terrain_given`` and
    ``size_given`` say whether ``--terrain`` and ``--size`` were given (battlefield has
    defaults of its own)."""

    terrain: str = "jacksboro"
    size: int = 512
    quick: bool = False
    grid: int | None = None
    lod: int = 16
    epsilon: float = 1.0
    visibility: str = "coarse"
    border: bool = True
    guard: int = 32
    full_sample: int | None = None
    sweeps: bool = True
    adopt: str = "newest"
    pace: str = "needed"
    max_error: float | None = None
    links: bool = True
    huge: bool = False
    full: bool = False
    path: str | None = None      # --path (timecritical; None: the experiment's own)
    vdp: float | None = None     # --vdp: ColorVideoVDP over this long of each played run
    terrain_given: bool = False  # --terrain given (battlefield: else its 4k² fractal store)
    size_given: bool = False     # --size given (battlefield: else its own 256²)


@dataclass
class Summary:
    """The table printed after a run: a title, column headings, rows of cell strings,
    then plain lines (``notes``) and the report's path."""

    title: str
    columns: tuple[str, ...]
    rows: list[tuple[str, ...]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    report: Path | None = None


@dataclass(frozen=True)
class Experiment:
    """One reproduction.

    ``configure(options)`` checks the options and returns the run's config (the paper's
    defaults, or its quick variant with ``options.quick``); ``run(config, out_dir,
    progress)`` measures, writes ``results.json``, the plots and ``report.md`` under
    ``out_dir`` and returns ``(results, report path)``; ``summary(results)`` gives the
    table to print."""

    name: str
    title: str
    configure: Callable[[Options], Any]
    run: Callable[[Any, Path, StageProgress | None], tuple[dict, Path]]
    summary: Callable[[dict], Summary]

    @property
    def default_out(self) -> Path:
        """``out/NAME``: where a run writes when no folder is given."""
        return Path("out") / self.name

    def reproduce(self, options: Options, out_dir: Path | None = None,
                  progress: StageProgress | None = None) -> tuple[dict, Summary]:
        """Configure, run (into ``out_dir``, default :attr:`default_out`: checked first,
        :func:`~lodsprite.files.writable_folder`) and summarise."""
        from lodsprite.files import writable_folder

        out = writable_folder(Path(out_dir or self.default_out))
        config = self.configure(options)
        results, report = self.run(config, out, progress)
        summary = self.summary(results)
        summary.report = report
        return results, summary


def single(progress: StageProgress | None, name: str) -> Progress | None:
    """A ``(done, total)`` callback reporting to ``progress`` as the step ``name``."""
    if progress is None:
        return None
    return lambda done, total: progress(name, done, total)


#: Sampled frames an experiment's quality figures take at least (its real configs).
MIN_QUALITY_FRAMES = 20


def split_sampled(frames: list[int]) -> tuple[list[int], list[int]]:
    """The sampled frames (indices along a path) in two interleaved halves,
    ``(chosen, reported)``: an experiment that picks one of several noisy rows picks it on
    ``chosen`` (every other sampled frame, from the second) and reports its figures on
    ``reported`` (the others, frame 0 among them), so that the row reported is not the
    one whose noise won the choice."""
    return list(frames[1::2]), list(frames[0::2])


class SplitSampled:
    """A config's sampled frames (its ``sample_frames``) in the two halves of
    :func:`split_sampled`: :attr:`chosen_frames` and :attr:`reported_frames`."""

    sample_frames: list[int]

    @property
    def chosen_frames(self) -> list[int]:
        """The sampled frames a row is chosen on."""
        return split_sampled(self.sample_frames)[0]

    @property
    def reported_frames(self) -> list[int]:
        """The sampled frames every figure is reported on."""
        return split_sampled(self.sample_frames)[1]
