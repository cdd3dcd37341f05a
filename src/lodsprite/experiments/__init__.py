"""The papers' reproductions as experiments, one package each, behind one registry.

Each of :mod:`~lodsprite.experiments.chen1999`, :mod:`~lodsprite.experiments.swan2002`,
:mod:`~lodsprite.experiments.scoggins2000`, :mod:`~lodsprite.experiments.sloan1997`,
:mod:`~lodsprite.experiments.gumbau`, :mod:`~lodsprite.experiments.large`,
:mod:`~lodsprite.experiments.battlefield` and :mod:`~lodsprite.experiments.timecritical`
holds its
run (``run.py``), its report (``report.py``), its defaults and its summary table, and
defines ``EXPERIMENT`` (an :class:`~lodsprite.experiments.base.Experiment`).  The papers'
published numbers are kept once, in :mod:`lodsprite.experiments.paper_numbers`.

``lodsprite reproduce NAME`` is ``get(NAME).reproduce(options, out_dir, progress)``.
Adding a reproduction is one package and one line in :data:`EXPERIMENTS`.  An
experiment's package is imported only when it is asked for (the swan2002 runner
drives the distributed layer).
"""

from __future__ import annotations

import importlib

from lodsprite.errors import InputError
from lodsprite.experiments.base import Experiment, Options, Summary

#: name -> the module defining its ``EXPERIMENT``.
EXPERIMENTS: dict[str, str] = {
    "chen1999": "lodsprite.experiments.chen1999",
    "swan2002": "lodsprite.experiments.swan2002",
    "scoggins2000": "lodsprite.experiments.scoggins2000",
    "sloan1997": "lodsprite.experiments.sloan1997",
    "gumbau": "lodsprite.experiments.gumbau",
    "large": "lodsprite.experiments.large",
    "battlefield": "lodsprite.experiments.battlefield",
    "timecritical": "lodsprite.experiments.timecritical",
}


def names() -> tuple[str, ...]:
    """The experiments' names, in the order the command line lists them."""
    return tuple(EXPERIMENTS)


def get(name: str) -> Experiment:
    """The experiment called ``name``; InputError naming the available ones otherwise."""
    if name not in EXPERIMENTS:
        raise InputError(f"unknown experiment '{name}': available: {', '.join(names())}")
    return importlib.import_module(EXPERIMENTS[name]).EXPERIMENT


__all__ = ["EXPERIMENTS", "Experiment", "Options", "Summary", "get", "names"]
