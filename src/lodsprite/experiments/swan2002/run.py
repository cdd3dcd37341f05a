"""Reproduction of Swan, Arango & Nakshatrala (2002) §4: the 600-frame timing study.

The swan2002 path is drawn in these set-ups, each as separate processes measured in the
same run (:data:`SETUPS`):

* ``inline`` - the 1999 algorithm, keyframes rendered in the client's own frame loop;
* ``separate`` - server and client pinned to different cores, one llvmpipe thread each
  (the paper's two machines, each with its own graphics pipe); skipped with fewer than
  two cores;
* ``same_cores`` - the same, but the server pinned to the client's core: the two
  programs share one "graphics pipe", as in the paper's non-distributed Figures 9-10,
  and nothing else changes;
* ``same_all_cores`` - server and client sharing all cores, llvmpipe's default threads;
* ``separate_continuous``, ``same_cores_continuous`` - as above with the paper's server,
  which renders keyframes back to back (pace ``continuous``) instead of when the client
  will need one (pace ``needed``, :mod:`lodsprite.distributed.pacing`);
* ``two_servers`` - two LOD servers and the client sharing all cores: keyframe rate and
  δt with 2 servers against ``same_all_cores``' 1;
* ``separate_bounded``, ``same_cores_bounded`` - ``separate`` and ``same_cores`` with the
  bounded client (``--max-error``, :data:`SwanConfig.max_error`): it renders its own
  keyframe when the shown one's error reaches the bound.  Every other client set-up is
  the paper's client (``--max-error off``), so each pair compares the two policies;
* ``separate_10mbit``, ``separate_100mbit``, ``separate_unlimited`` - server and client
  on two hosts (network namespaces joined by a veth pair, rate-limited with tc's token
  bucket: the paper's 10BASE-T and its proposed 100BASE-T), and
  ``separate_10mbit_zlib`` with compressed keyframes; skipped where this process may
  not create namespaces (:mod:`lodsprite.distributed.netns`).

Each set-up's folder holds the client's ``frames.csv``, ``summary.json``,
``keyframes.json`` and the server's per-keyframe statistics; ``results.json`` gathers
them with the prediction error of each predictor on the same path, ahead by the measured
δt.  After its timed frames each run replays its frames untimed, in its own process,
through the harness (``--ground-truth --quality-stride``, :mod:`lodsprite.distributed.
quality`): the error metric of each frame against the keyframe it showed and, every
``quality_stride`` frames, RMSE against full resolution (``image`` in each set-up's
results, gathered from the run's ``frames.csv`` and ``summary.json``).  ``policies``
sets each bounded set-up beside its paper counterpart (:data:`POLICY_PAIRS`): frame-time
σ and p99, the shown error's mean, p99 and maximum, and the share of frames at or
above ε.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
from contextlib import ExitStack
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from lodsprite.distributed.client import DEFAULT_MAX_ERROR
from lodsprite.distributed.netns import RATES, SERVER_IP, available, two_hosts
from lodsprite.distributed.quality import QUALITY_KEYS, error_summary
from lodsprite.distributed.run import local_server, lodsprite_command, pinned, server_process
from lodsprite.errors import LodspriteError
from lodsprite.files import write_json
from lodsprite.paths import swan2002
from lodsprite.progress import Progress
from lodsprite.scene import load_scene
from lodsprite.sprite.predictors import PREDICTORS, prediction_error

NS_PORT = 5555
ONE_THREAD = {"LP_NUM_THREADS": "1"}


@dataclass(frozen=True)
class Setup:
    """Where the programs run: ``client``/``server`` are ``"own"`` (pinned to a core of its
    own, one llvmpipe thread), ``"shared"`` (the server on the client's core) or
    ``"all"`` (every core, default threads); ``link`` a key of ``netns.RATES`` (two
    hosts); ``pace`` overrides the run's; ``codec`` is the server's."""

    client: str = "own"
    server: str = "own"
    servers: int = 1
    pace: str | None = None  # None: the run's pace
    codec: str = "raw"
    link: str | None = None
    bounded: bool = False  # the client bounds the shown error (--max-error)

    @property
    def cores(self) -> int:
        return 2 if self.server == "own" else 1


SETUPS: dict[str, Setup | None] = {
    "inline": None,
    "same_cores": Setup(server="shared"),
    "separate": Setup(),
    "same_all_cores": Setup(client="all", server="all"),
    "same_cores_continuous": Setup(server="shared", pace="continuous"),
    "separate_continuous": Setup(pace="continuous"),
    "two_servers": Setup(client="all", server="all", servers=2),
    **{f"separate_{name}": Setup(link=name) for name in RATES},
    "separate_10mbit_zlib": Setup(link="10mbit", codec="zlib"),
    "separate_bounded": Setup(bounded=True),
    "same_cores_bounded": Setup(server="shared", bounded=True),
}
LINK_SETUPS = tuple(k for k, v in SETUPS.items() if v is not None and v.link)
#: (the paper's client, the bounded client) on the same placement.
POLICY_PAIRS = (("separate", "separate_bounded"), ("same_cores", "same_cores_bounded"))


@dataclass(frozen=True)
class SwanConfig:
    terrain: str = "jacksboro"
    frames: int = 600
    size: int = 512
    lod: int = 16
    predictor: str = "linear"
    adopt: str = "newest"
    pace: str = "needed"
    links: bool = True
    quality_stride: int = 10  # replay every n-th frame for image quality (0: none)
    epsilon: float = 1.0      # ε, pixels: the servers' pacing and the replayed error's
    max_error: float = DEFAULT_MAX_ERROR  # the bounded client's --max-error, pixels

    @classmethod
    def quick(cls, **kw) -> SwanConfig:
        return cls(**{"frames": 60, "size": 256, **kw})

    def args(self) -> list[str]:
        """Options shared by ``render --mode sprite`` (inline) and ``client``: with a
        quality stride, each run replays its frames untimed against full resolution."""
        quality = (["--ground-truth", "--quality-stride", str(self.quality_stride)]
                   if self.quality_stride else [])
        return ["--terrain", self.terrain, "--path", "swan2002", "--frames", str(self.frames),
                "--size", f"{self.size}x{self.size}", "--lod", str(self.lod),
                "--epsilon", str(self.epsilon), *quality]

    def client_args(self, bounded: bool) -> list[str]:
        """``lodsprite client`` options: shared ones, pace, adoption rule and the bound."""
        return [*self.args(), "--pace", self.pace, "--adopt", self.adopt,
                "--max-error", str(self.max_error) if bounded else "off"]


def _run(cmd: list[str], cpus: set[int] | None = None, env: dict | None = None) -> None:
    proc = subprocess.run(cmd, capture_output=True, text=True, preexec_fn=pinned(cpus),
                          env={**os.environ, **(env or {})}, timeout=1800)
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise LodspriteError(f"{' '.join(cmd[3:5])} failed: {last}")


def _placement(where: str, own: int, cpus: list[int]) -> tuple[set[int] | None, dict | None]:
    if where == "all":
        return None, None
    return {cpus[own] if where == "own" else cpus[0]}, ONE_THREAD


def run_setup(cfg: SwanConfig, name: str, out: Path, cpus: list[int]) -> dict | None:
    """Run set-up ``name`` (a key of ``SETUPS``) as real processes, outputs in ``out``;
    its collected figures, or None when this machine has too few cores for it."""
    setup = SETUPS[name]
    if setup is None:
        _run(lodsprite_command("render", "--mode", "sprite", *cfg.args(), "--out", str(out)))
        return _collect(name, out)
    if len(cpus) < setup.cores:
        return None
    run_cfg = replace(cfg, pace=setup.pace or cfg.pace)
    client_cpus, client_env = _placement(setup.client, 0, cpus)
    server_cpus, server_env = _placement(setup.server, 1, cpus)
    if setup.link is not None:
        _two_hosts(run_cfg, setup, out, (client_cpus, client_env), (server_cpus, server_env))
        return _collect(name, out)
    serve = ["--predictor", cfg.predictor, "--codec", setup.codec]
    with ExitStack() as stack:
        addresses = [stack.enter_context(local_server(serve, server_cpus, server_env))
                     for _ in range(setup.servers)]
        servers = [a for address in addresses for a in ("--server", address)]
        _run(lodsprite_command("client", *servers, *run_cfg.client_args(setup.bounded),
                               "--out", str(out)), client_cpus, client_env)
    return _collect(name, out)


def _two_hosts(cfg: SwanConfig, setup: Setup, out: Path, client: tuple, server: tuple) -> None:
    """Server and client in two network namespaces joined by a (rate-limited) veth."""
    address = f"{SERVER_IP}:{NS_PORT}"
    with two_hosts(RATES[setup.link]) as hosts:
        serve = hosts.server(lodsprite_command("serve", "--bind", address, "--allow-remote",
                                               "--predictor", cfg.predictor,
                                               "--codec", setup.codec))
        with server_process(serve, *server):
            _run(hosts.client(lodsprite_command("client", "--server", address,
                                                *cfg.client_args(setup.bounded),
                                                "--out", str(out))), *client)


def _collect(setup: str, out: Path) -> dict:
    with (out / "frames.csv").open() as f:
        rows = list(csv.DictReader(f))
    ms = np.array([float(r["ms"]) for r in rows])
    key = "keyframe"
    received = sum(r["kind"] == key for r in rows)
    res = {"client_ms_mean": float(ms.mean()), "client_ms_std": float(ms.std()),
           "client_ms_median": float(np.median(ms)),
           "client_ms_p99": float(np.percentile(ms, 99)),
           # stutter: RMS of the change from one frame's time to the next (slow changes
           # of the scene's cost along the path hardly count, unlike in σ)
           "client_ms_jitter": float(np.sqrt(np.mean(np.diff(ms) ** 2))) if len(ms) > 1 else 0.0,
           "keyframes": received,
           "local_keyframes": sum(r["kind"] == "local_keyframe" for r in rows),
           "keyframe_rate_hz": received / (ms.sum() / 1e3),
           "sprites_per_keyframe": (len(rows) - received) / received if received else None,
           "per_frame_ms": ms.tolist(), "per_frame_type": [r["kind"] for r in rows]}
    summary = json.loads((out / "summary.json").read_text())
    # each frame's error metric (the inline engine's own; the client's measured untimed
    # after its run) and, with --ground-truth, the image quality of the run's replay
    errors = np.array([float(r["error_px"]) for r in rows])
    res["image"] = {**error_summary(errors, summary["epsilon"]),
                    **{k: summary[k] for k in QUALITY_KEYS if k in summary}}
    stats_file = out / "server_stats.json"
    if setup != "inline" and stats_file.exists():
        every = json.loads(stats_file.read_text())["stats"] or [{}]
        stats = {k: [v for s in every for v in s.get(k, [])] for k in every[0]
                 if isinstance(every[0][k], list)}
        res["max_error"] = summary.get("max_error")
        res["rejected_keyframes"] = summary.get("rejected_keyframes")
        res["server"] = every[0]
        res["servers"] = len(every)
        for k in ("delta_t", "production", "transmission", "render", "viewpoint_wait", "paced",
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
    hf = load_scene(cfg.terrain, textured=False).hf  # the path follows the heights
    path = swan2002(hf, cfg.frames)
    times = np.cumsum(ref["per_frame_ms"]) / 1e3
    lead = max(1, round(ref["delta_t_ms_mean"] / ref["client_ms_mean"]))
    lead = min(lead, cfg.frames // 4)
    return {"lead_frames": lead, **{name: prediction_error(cls(), times, list(path.viewpoints),
                                                           lead)
                                    for name, cls in PREDICTORS.items()}}


#: What :func:`policies` sets side by side: (results key, where it lies).
POLICY_MEASURES = (("client_ms_std", None), ("client_ms_p99", None), ("client_ms_mean", None),
                   ("error_px_mean", "image"), ("error_px_p99", "image"),
                   ("error_px_max", "image"), ("over_epsilon", "image"),
                   ("keyframes", None), ("local_keyframes", None))


def policies(results: dict) -> list[dict]:
    """Each pair of :data:`POLICY_PAIRS` that ran: ``{"setup", "max_error", "paper": {...},
    "bounded": {...}}`` with the :data:`POLICY_MEASURES` of both clients."""
    out = []
    for paper, bounded in POLICY_PAIRS:
        a, b = results.get(paper) or {}, results.get(bounded) or {}
        if "client_ms_mean" not in a or "client_ms_mean" not in b:
            continue

        def pick(r: dict) -> dict:
            return {k: (r.get(where) or {}).get(k) if where else r.get(k)
                    for k, where in POLICY_MEASURES}

        out.append({"setup": paper, "max_error": b.get("max_error"),
                    "paper": pick(a), "bounded": pick(b)})
    return out


def reproduce_swan2002(cfg: SwanConfig, out_dir: Path,
                       progress: Progress | None = None) -> dict:
    """Run the three set-ups; write ``results.json`` and return it (plots: :mod:`.report`)."""
    out_dir = Path(out_dir)
    cpus = sorted(os.sched_getaffinity(0))
    results: dict = {"experiment": "swan2002", "config": asdict(cfg), "cpus": len(cpus)}
    no_netns = available() if cfg.links else "not asked for (--no-links)"
    setups = list(SETUPS)
    for i, setup in enumerate(setups):
        if setup in LINK_SETUPS and no_netns:
            results[setup] = {"skipped": f"two hosts on one machine: {no_netns}"}
            continue
        res = run_setup(cfg, setup, out_dir / setup, cpus)
        results[setup] = res if res is not None else {
            "skipped": "needs at least two cores to pin server and client apart"}
        if progress:
            progress(i + 1, len(setups) + 1)
    results["prediction"] = _prediction(cfg, results)
    results["policies"] = policies(results)
    if progress:
        progress(len(setups) + 1, len(setups) + 1)
    write_json(out_dir / "results.json", results)
    return results
