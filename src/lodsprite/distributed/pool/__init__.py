"""The render pool (issue 24): a broker (:mod:`.broker`) handing keyframe jobs
(:mod:`.jobs`) to render workers (:mod:`.render_worker`), local processes or other hosts, with
the ZeroMQ guide's Paranoid Pirate heartbeats."""

from lodsprite.distributed.pool.broker import MAX_TRIES, Broker, WorkerInfo
from lodsprite.distributed.pool.jobs import HEARTBEAT_S, LIVENESS_S, Job, Result
from lodsprite.distributed.pool.render_process import resolve_load
from lodsprite.distributed.pool.render_worker import Worker

__all__ = ["HEARTBEAT_S", "LIVENESS_S", "MAX_TRIES", "Broker", "Job", "Result", "Worker",
           "WorkerInfo", "resolve_load"]
