"""The ``cluster`` extra: Dask distributed, for the commands that take ``--scheduler``.

Dask is optional (``pip install 'lodsprite[cluster]'``).  Every user of a scheduler
(profile generation, the terrain store's tile build) goes through this module, which
imports Dask only when a scheduler is asked for and otherwise names the extra in one
line.  It sits at the bottom of the package: it imports nothing of lodsprite but
:mod:`lodsprite.errors`, so profiles/ and terrain/ both use it without reaching into
each other.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

from lodsprite.errors import InputError

CLUSTER_EXTRA = "lodsprite[cluster]"
DASK_CONNECT_TIMEOUT_S = 10.0
"""How long :func:`connect` waits for the scheduler (seconds)."""


def require_dask() -> ModuleType:
    """The ``dask.distributed`` module, or :class:`InputError` naming the extra that
    installs it (``--scheduler`` is the only use of Dask; a lean install has none)."""
    try:
        import dask.distributed as dask_distributed
    except ImportError:
        raise InputError(f"--scheduler needs Dask distributed: pip install '{CLUSTER_EXTRA}'"
                         ) from None
    return dask_distributed


def connect(address: str) -> Any:
    """A ``dask.distributed.Client`` of the scheduler at ``address`` (``tcp://host:port``),
    waiting at most :data:`DASK_CONNECT_TIMEOUT_S`; :class:`InputError` when Dask is
    missing or the scheduler cannot be reached."""
    dask_distributed = require_dask()
    try:
        return dask_distributed.Client(address, timeout=f"{DASK_CONNECT_TIMEOUT_S}s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError(f"cannot reach the Dask scheduler at {address}: {exc}") from None
