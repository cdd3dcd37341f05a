"""Reproduction of Swan, Arango & Nakshatrala (2002) §4: the 600-frame timing study.

The swan2002 path is drawn in three set-ups, each as separate processes measured in
the same run:

* ``inline`` - the 1999 algorithm, keyframes rendered in the client's own frame loop;
* ``same_cores`` - LOD server and LOD client sharing all cores (the paper's
  non-distributed Figures 9-10);
* ``separate`` - server and client pinned to different cores, one llvmpipe thread each
  (the paper's two machines); skipped with fewer than two cores;
* ``two_servers`` - two LOD servers and the client sharing all cores: keyframe rate and
  δt with 2 servers against ``same_cores``' 1;
* ``separate_10mbit``, ``separate_100mbit``, ``separate_unlimited`` - the same, with server
  and client on two hosts (network namespaces joined by a veth pair, rate-limited with
  tc's token bucket: the paper's 10BASE-T and its proposed 100BASE-T); skipped where
  this process may not create namespaces (:mod:`lodsprite.distributed.netns`).

Each set-up's folder holds the client's ``frames.csv``, ``summary.json`` and the
server's per-keyframe statistics; ``results.json`` gathers them with the prediction
error of each predictor on the same path, ahead by the measured δt.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from lodsprite.distributed.netns import RATES, SERVER_IP, available, two_hosts
from lodsprite.distributed.predictors import PREDICTORS, prediction_error
from lodsprite.distributed.run import local_server, lodsprite_command, pinned, server_process
from lodsprite.errors import LodspriteError
from lodsprite.paths import swan2002
from lodsprite.report.io import write_json
from lodsprite.terrain import load_terrain

SETUPS = ("inline", "same_cores", "separate", "two_servers")
LINK_SETUPS = tuple(f"separate_{name}" for name in RATES)
NS_PORT = 5555
ONE_THREAD = {"LP_NUM_THREADS": "1"}


@dataclass(frozen=True)
class SwanConfig:
    terrain: str = "jacksboro"
    frames: int = 600
    size: int = 512
    lod: int = 16
    predictor: str = "linear"
    adopt: str = "newest"
    links: bool = True

    @classmethod
    def quick(cls, **kw) -> SwanConfig:
        return cls(**{"frames": 150, "size": 256, **kw})

    def args(self) -> list[str]:
        return ["--terrain", self.terrain, "--path", "swan2002", "--frames", str(self.frames),
                "--size", f"{self.size}x{self.size}", "--lod", str(self.lod)]


def _run(cmd: list[str], cpus: set[int] | None = None, env: dict | None = None) -> None:
    proc = subprocess.run(cmd, capture_output=True, text=True, preexec_fn=pinned(cpus),
                          env={**os.environ, **(env or {})}, timeout=1800)
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise LodspriteError(f"{' '.join(cmd[3:5])} failed: {last}")


def _setup(cfg: SwanConfig, setup: str, out: Path, cpus: list[int]) -> dict | None:
    if setup == "inline":
        _run(lodsprite_command("render", "--mode", "sprite", *cfg.args(), "--out", str(out)))
    elif setup == "same_cores":
        with local_server(cfg.predictor) as address:
            _run(lodsprite_command("client", "--server", address, *cfg.args(), "--adopt",
                                   cfg.adopt, "--out", str(out)))
    elif setup == "two_servers":
        with local_server(cfg.predictor) as a, local_server(cfg.predictor) as b:
            _run(lodsprite_command("client", "--server", a, "--server", b, *cfg.args(),
                                   "--adopt", cfg.adopt, "--out", str(out)))
    elif setup in LINK_SETUPS:
        if len(cpus) < 2:
            return None
        _two_hosts(cfg, RATES[setup.removeprefix("separate_")], out, cpus)
    else:
        if len(cpus) < 2:
            return None
        with local_server(cfg.predictor, {cpus[1]}, ONE_THREAD) as address:
            _run(lodsprite_command("client", "--server", address, *cfg.args(), "--adopt",
                                   cfg.adopt, "--out", str(out)), {cpus[0]}, ONE_THREAD)
    return _collect(setup, out)


def _two_hosts(cfg: SwanConfig, rate: str | None, out: Path, cpus: list[int]) -> None:
    """Server and client in two network namespaces joined by a (rate-limited) veth."""
    address = f"{SERVER_IP}:{NS_PORT}"
    with two_hosts(rate) as hosts:
        serve = hosts.server(lodsprite_command("serve", "--bind", address, "--allow-remote",
                                               "--predictor", cfg.predictor))
        with server_process(serve, {cpus[1]}, ONE_THREAD):
            _run(hosts.client(lodsprite_command("client", "--server", address, *cfg.args(),
                                                "--adopt", cfg.adopt, "--out", str(out))),
                 {cpus[0]}, ONE_THREAD)


def _collect(setup: str, out: Path) -> dict:
    with (out / "frames.csv").open() as f:
        rows = list(csv.DictReader(f))
    ms = np.array([float(r["ms"]) for r in rows])
    key = "keyframe"
    received = sum(r["type"] == key for r in rows)
    res = {"client_ms_mean": float(ms.mean()), "client_ms_std": float(ms.std()),
           "client_ms_median": float(np.median(ms)),
           "client_ms_p99": float(np.percentile(ms, 99)),
           "keyframes": received,
           "keyframe_rate_hz": received / (ms.sum() / 1e3),
           "sprites_per_keyframe": (len(rows) - received) / received if received else None,
           "per_frame_ms": ms.tolist(), "per_frame_type": [r["type"] for r in rows]}
    stats_file = out / "server_stats.json"
    if setup != "inline" and stats_file.exists():
        every = json.loads(stats_file.read_text())["stats"] or [{}]
        stats = {k: [v for s in every for v in s.get(k, [])] for k in every[0]
                 if isinstance(every[0][k], list)}
        res["server"] = every[0]
        res["servers"] = len(every)
        for k in ("delta_t", "production", "transmission", "render", "viewpoint_wait",
                  "queue_insert", "queue_retrieve"):
            vals = stats.get(f"{k}_ms", [])
            res[f"{k}_ms_mean"] = float(np.mean(vals)) if vals else None
    return res


def _prediction(cfg: SwanConfig, results: dict) -> dict:
    """Eye and view-direction error of each predictor on the swan2002 path, predicting as
    far ahead as the measured δt (in the client's own frame times)."""
    ref = results.get("separate") or results.get("same_cores")
    if not ref or not ref.get("delta_t_ms_mean"):
        return {}
    hf = load_terrain(cfg.terrain)
    path = swan2002(hf, cfg.frames)
    times = np.cumsum(ref["per_frame_ms"]) / 1e3
    lead = max(1, round(ref["delta_t_ms_mean"] / ref["client_ms_mean"]))
    lead = min(lead, cfg.frames // 4)
    return {"lead_frames": lead, **{name: prediction_error(cls(), times, list(path.viewpoints),
                                                           lead)
                                    for name, cls in PREDICTORS.items()}}


def reproduce_swan2002(cfg: SwanConfig, out_dir: Path,
                       progress: Callable[[int, int], None] | None = None) -> dict:
    """Run the three set-ups; write ``results.json`` and return it (plots: report.swan2002)."""
    out_dir = Path(out_dir)
    cpus = sorted(os.sched_getaffinity(0))
    results: dict = {"experiment": "swan2002", "config": asdict(cfg), "cpus": len(cpus)}
    no_netns = available() if cfg.links else "not asked for (--no-links)"
    setups = SETUPS + LINK_SETUPS
    for i, setup in enumerate(setups):
        if setup in LINK_SETUPS and no_netns:
            results[setup] = {"skipped": f"two hosts on one machine: {no_netns}"}
            continue
        res = _setup(cfg, setup, out_dir / setup, cpus)
        results[setup] = res if res is not None else {
            "skipped": "needs at least two cores to pin server and client apart"}
        if progress:
            progress(i + 1, len(setups) + 1)
    results["prediction"] = _prediction(cfg, results)
    if progress:
        progress(len(setups) + 1, len(setups) + 1)
    write_json(out_dir / "results.json", results)
    return results
