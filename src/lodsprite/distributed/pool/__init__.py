"""The render pools of ``serve --web`` and the notebook widgets: the local pool
(:mod:`.local_pool`, one renderer a process of this machine) and, with ``--ray``, Ray
actors on a cluster's machines (:mod:`.ray_pool`, imported only then); both keep their
jobs in :mod:`.dispatch`'s table and render with :mod:`.render_process`."""

from lodsprite.distributed.pool.dispatch import JOB_TIMEOUT_S, MAX_TRIES
from lodsprite.distributed.pool.jobs import Job, Result, WorkerInfo
from lodsprite.distributed.pool.local_pool import LocalPool
from lodsprite.distributed.pool.render_process import resolve_load

__all__ = ["JOB_TIMEOUT_S", "MAX_TRIES", "Job", "LocalPool", "Result", "WorkerInfo",
           "resolve_load"]
