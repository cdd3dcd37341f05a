"""The render pools of ``serve --web``: the local pool (issue 24), a broker (:mod:`.broker`)
handing keyframe jobs (:mod:`.jobs`) to local render worker processes
(:mod:`.render_worker`) with the ZeroMQ guide's Paranoid Pirate heartbeats; and, with
``--ray``, Ray actors on a cluster's machines (:mod:`.ray_pool`, imported only then)."""

from lodsprite.distributed.pool.broker import MAX_TRIES, Broker, WorkerInfo
from lodsprite.distributed.pool.jobs import HEARTBEAT_S, LIVENESS_S, Job, Result
from lodsprite.distributed.pool.render_process import resolve_load
from lodsprite.distributed.pool.render_worker import Worker

__all__ = ["HEARTBEAT_S", "LIVENESS_S", "MAX_TRIES", "Broker", "Job", "Result", "Worker",
           "WorkerInfo", "resolve_load"]
