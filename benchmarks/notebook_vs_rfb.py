"""The notebook widgets side by side in a real JupyterLab, over an added latency.

Two widgets fly the same terrain along the same path in the same JupyterLab 4, opened by
headless Chromium (Debian's, SwiftShader WebGL2, driven by selenium):

* ``sprite``: :class:`lodsprite.notebook.sprite.SpriteWidget`, the page's client in the
  cell: every display frame a spriteframe drawn in the browser, keyframes from the
  kernel's renderer process;
* ``rfb``: :class:`lodsprite.notebook.stream.StreamWidget` (jupyter_rfb): every frame
  rendered in the kernel at full detail and sent as a JPEG (quality 80), at most two
  frames in flight, the convention of PyVista, pygfx and vispy in Jupyter.

The latency is added between the page and the kernel: the browser reaches JupyterLab
through a delay proxy (a process of its own, :class:`web_vs_streaming.DelayProxy`) that
holds every chunk half the round trip in each direction; the kernel and the server
talk over local ZeroMQ as usual.  Nothing of the measurement runs in the measured
processes' threads.

Per latency and widget, with the same untimed warm-up for both (the path played once:
the renderer started, the data loaded, the first keyframe shown), then the figures
started again (``reset_stats``) and the path played again, timed:

* frame time median and p99 (ms between new frames on the page): for ``sprite`` the
  page's own frame intervals (``requestAnimationFrame``, each frame a new spriteframe);
  for ``rfb`` the intervals between the frames the page put on screen (jupyter_rfb's
  frame feedback, the page's clock);
* input to frame (ms): after the path, ``--presses`` real key presses (selenium's,
  trusted events, 'w' held 0.2 s) into the focused view, each from its event's time to
  the display frame (``requestAnimationFrame``) that presents the first frame drawn from
  a camera that includes it: the page moves its camera and draws on its next frame;
  streaming draws the kernel's frame rendered after the press once it has loaded;
* shown error (px, mean over the path's frames): the page's estimate for ``sprite``
  (parallax from the keyframe's viewpoint and the squares drawn from the fallback, the
  HUD's figure); none for ``rfb``.  The stream's input times are jupyter_rfb's
  handler's (``performance.now()`` as it runs), the sprite page's the key event's own
  ``timeStamp``: a bias towards the stream of the event's wait on the page's main thread;
* RMSE (grey levels) of the images each widget shows, against the band-limited
  reference (:func:`lodsprite.harness.scene_reference`, level 0 at 4x4 samples a pixel)
  at the viewpoint each shows: in a third, judged pass of the path (after the timed one,
  its figures not timed), every ``--judge-every``-th path frame is kept as it is drawn:
  the sprite page's canvas (``capture``: a readback in those frames, which the timed
  pass never does) and the stream's frame as the kernel rendered it, then compressed
  and decoded as jupyter_rfb sends it (JPEG at the widget's quality).  Both widgets play
  a path one viewpoint a frame, so the frame shown for path index ``k`` is judged at
  viewpoint ``k``; its mean over the kept frames is ``rmse_shown``.

    python benchmarks/notebook_vs_rfb.py [--latencies 0,50,150] [--quick] [--json F]

Targets (issue 33): ``sprite`` at 150 ms: p99 <= 2x median, input to frame one display
frame; ``sprite`` mean shown error <= 2 epsilon along chen1999.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve()
ROOT = HERE.parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "notebook")]

MODES = ("sprite", "rfb")
#: The page's recorder: the display frames (requestAnimationFrame times) and the images
#: loaded (jupyter_rfb's frames), in the page's clock (ms), the newest kept.
RECORDER_JS = """
if (!window.__rec) {
  const rec = window.__rec = {raf: [], load: []};
  const keep = (a, t) => { a.push(t); if (a.length > 40000) a.splice(0, 20000); };
  const loop = (t) => { keep(rec.raf, t); requestAnimationFrame(loop); };
  requestAnimationFrame(loop);
  document.addEventListener('load', (e) => {
    if (e.target && e.target.tagName === 'IMG') keep(rec.load, performance.now());
  }, true);
}
return performance.timeOrigin;
"""
#: The sprite page's figures at the end of the timed path (the view's client API).
SPRITE_TIMED_JS = """
const done = arguments[arguments.length - 1];
const wait = () => {
  const box = document.querySelector('.lodsprite-widget');
  const api = box && box.lodsprite;
  if (api && String(api.state()).startsWith('playing')) {
    api.finished.then(() => done(api.stats()));
  } else setTimeout(wait, 2);
};
wait();
"""
SPRITE_STATS_JS = "return document.querySelector('.lodsprite-widget').lodsprite.stats();"
SHUTDOWN_JS = """
const done = arguments[arguments.length - 1];
window.jupyterapp.serviceManager.sessions.shutdownAll().then(
  () => done(true), (e) => done(String(e)));
"""
VIEW_CSS = {"sprite": ".lodsprite-widget canvas", "rfb": ".renderview-view"}
API_JS = "document.querySelector('.lodsprite-widget').lodsprite"


# ------------------------------------------------------------------ the notebook

def cells(mode: str, args) -> list[str]:
    """The benchmark's notebook: the widget; then, in a task on the kernel's loop (the
    cell ends and the kernel is idle while the widgets play: the browser holds widget
    state updates, jupyter_rfb's frame feedback among them, while a cell runs), the
    warm-up, the timed path, and the kernel's logs once the driver has pressed its keys."""
    w, h = args.size
    kw = f"size=({w}, {h})" + (f", grid={args.grid}" if args.grid else "")
    if mode == "sprite":
        kw += f", epsilon={args.epsilon}" + (f", lod={args.lod}" if args.lod else "")
    play = f"w.play({args.path!r}, frames={args.frames}); n = await w.played(timeout=600)"
    judged = list(range(0, args.frames, args.judge_every))
    return [
        "import asyncio, json, os, time\nimport lodsprite\n"
        f"w = lodsprite.widget({args.terrain!r}, stream={mode == 'rfb'}, {kw})\nw",
        "async def bench():\n"
        f"    {play}  # the warm-up, untimed\n"
        "    w.reset_stats()\n"
        "    open('warm', 'w').write(str(time.time()))\n"
        f"    {play}\n"
        "    stats = dict(w.stats)\n"
        "    open('timed', 'w').write(str(n))\n"
        "    while not os.path.exists('pressed'):\n"
        "        await asyncio.sleep(0.05)\n"
        "    await asyncio.sleep(1.0)  # the last frames' feedback\n"
        "    json.dump({'played': n, 'stats': stats,\n"
        "               'shown': list(getattr(w, 'shown', [])),\n"
        "               'drawn': list(getattr(w, 'drawn', [])),\n"
        "               'inputs': list(getattr(w, 'inputs', []))}, open('result.json', 'w'))\n"
        "    while not os.path.exists('judge'):  # the judged pass, untimed\n"
        "        await asyncio.sleep(0.05)\n"
        f"    keep, kept = set({judged!r}), {{}}\n"
        "    if hasattr(w, 'get_frame'):  # the stream: each kept frame as rendered\n"
        "        draw = w.get_frame\n"
        "        def get_frame():\n"
        "            i = w._path_index\n"
        "            image = draw()\n"
        "            if image is not None and i in keep and i < len(w._path):\n"
        "                vp = w._path[i]\n"
        "                kept[i] = (image.copy(), [*vp.x, *vp.y, *vp.z, *vp.o])\n"
        "            return image\n"
        "        w.get_frame = get_frame\n"
        f"    {play}\n"
        "    if kept:\n"
        "        import numpy as np\n"
        "        ks = sorted(kept)\n"
        "        np.savez('judged.npz', index=np.array(ks),\n"
        "                 images=np.stack([kept[k][0] for k in ks]),\n"
        "                 vps=np.array([kept[k][1] for k in ks]), quality=w.quality)\n"
        "    open('judged', 'w').write('1')\n"
        "    w.close()\n\n"
        "def failed(task):\n"
        "    if task.exception() is not None:\n"
        "        open('failed', 'w').write(repr(task.exception()))\n\n"
        "task = asyncio.ensure_future(bench())\ntask.add_done_callback(failed)",
    ]


def write_notebook(folder: Path, mode: str, args) -> str:
    import nbformat

    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_code_cell(c) for c in cells(mode, args)]
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3",
                                 "language": "python"}
    name = f"bench_{mode}.ipynb"
    nbformat.write(nb, folder / name)
    return name


# ------------------------------------------------------------------ the figures

def percentiles(values, ps=(50, 99)) -> list[float | None]:
    a = np.asarray(values, dtype=np.float64)
    return [float(np.percentile(a, p)) if a.size else None for p in ps]


def rfb_frames(result: dict, frames: int) -> list[float]:
    """The page's intervals (ms) between the timed path's frames put on screen: the
    frames the widget rendered (``drawn``), not jupyter_rfb's lossless re-sends of the
    last one (a PNG 0.3 s after a JPEG when no frame follows), which take indices too."""
    path = set(result["drawn"][:frames])
    times = sorted(t for i, t in result["shown"] if i in path)
    return list(np.diff(np.asarray(times) * 1e3))


def rfb_input_ms(result: dict, origin_ms: float, rec: dict) -> list[float]:
    """Each key press's event time to the display frame presenting the first frame
    rendered after it: its image handed to the page (feedback), loaded, then the next
    ``requestAnimationFrame``; all in the page's clock (ms)."""
    shown = sorted(result["shown"])
    index = np.array([i for i, _ in shown])
    put = np.array([t * 1e3 - origin_ms for _, t in shown])  # wall clock -> page clock
    loads, rafs = np.sort(rec["load"]), np.sort(rec["raf"])
    out = []
    for t_event, frame in result["inputs"]:
        k = np.searchsorted(index, frame)
        if k == len(index):
            continue  # never shown before the logs were written
        j = np.searchsorted(loads, put[k])
        if j == len(loads):
            continue
        r = np.searchsorted(rafs, loads[j], side="right")
        if r < len(rafs):
            out.append(float(rafs[r] - 1e3 * t_event))
    return out


def figures(mode: str, result: dict, page: dict, args) -> dict:
    if mode == "sprite":
        timed = page["timed"]
        return {"frame_ms_median": timed["median_ms"], "frame_ms_p99": timed["p99_ms"],
                "frames": timed["frames"], "keyframes": timed["keyframes"],
                "keyframe_latency_ms": timed["latency_ms"],
                "input_to_frame_ms": page["after"]["input_ms"],
                "input_to_frame_ms_p99": page["after"]["input_ms_p99"],
                "inputs": page["after"]["inputs"],
                "error_px_mean": timed["error_px_mean"]}
    intervals = rfb_frames(result, args.frames)
    med, p99 = percentiles(intervals)
    inputs = rfb_input_ms(result, page["origin_ms"], page["rec"])
    imed, ip99 = percentiles(inputs)
    return {"frame_ms_median": med, "frame_ms_p99": p99, "frames": len(intervals) + 1,
            "keyframes": len(intervals) + 1, "keyframe_latency_ms": None,
            "input_to_frame_ms": imed, "input_to_frame_ms_p99": ip99,
            "inputs": len(inputs), "error_px_mean": None,  # full detail at its own viewpoint
            "kernel_render_ms": result["stats"].get("render_ms")}


# ------------------------------------------------------------------ shown images, judged

def page_frames(captured: list[dict]) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """The sprite page's kept frames: (path index, viewpoint's 12 numbers, (h, w, 3) uint8
    image top row first) from its ``captured()`` (RGBA rows bottom-up, base64)."""
    import base64

    out = []
    for c in captured:
        rgba = np.frombuffer(base64.b64decode(c["rgba"]), np.uint8)
        image = rgba.reshape(c["height"], c["width"], 4)[::-1, :, :3]
        vp = c["vp"]
        out.append((int(c["index"]), np.array([*vp["x"], *vp["y"], *vp["z"], *vp["o"]]),
                    np.ascontiguousarray(image)))
    return out


def stream_frames(npz: Path) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """The stream's kept frames as the page gets them: each compressed by jupyter_rfb at
    the widget's quality (JPEG, PNG where no JPEG encoder is installed) and decoded."""
    import imageio.v3 as iio
    from jupyter_rfb._utils import array2compressed

    data = np.load(npz)
    out = []
    for k, vp, image in zip(data["index"], data["vps"], data["images"], strict=True):
        _, payload = array2compressed(image, quality=int(data["quality"]))
        shown = np.asarray(iio.imread(payload))[..., :3]
        out.append((int(k), vp, shown))
    return out


_REFERENCE: dict = {}


def reference(args, vp12: np.ndarray) -> np.ndarray:
    """The band-limited reference at a viewpoint (12 numbers) of the widgets' terrain,
    size and field of view (45°, both widgets' default), drawn once per viewpoint."""
    from lodsprite import Renderer, open_scene
    from lodsprite.camera import Viewpoint
    from lodsprite.harness import scene_reference

    if "draw" not in _REFERENCE:
        renderer = Renderer(open_scene(args.terrain), size=args.size, fov_y_deg=45.0)
        ctx = scene_reference(renderer)
        _REFERENCE.update(draw=ctx.__enter__(), ctx=ctx, images={})
    key = np.round(np.asarray(vp12, np.float64), 6).tobytes()
    images = _REFERENCE["images"]
    if key not in images:
        v = np.asarray(vp12, np.float64)
        images[key] = _REFERENCE["draw"](Viewpoint(v[0:3], v[3:6], v[6:9], v[9:12]))
    return images[key]


def judge(shown: list[tuple[int, np.ndarray, np.ndarray]], args) -> dict:
    """RMSE of each kept frame against the reference at its viewpoint: the mean and the
    frames judged."""
    from lodsprite.metrics import rmse

    errors = [rmse(image, reference(args, vp)) for _, vp, image in shown]
    return {"rmse_shown": float(np.mean(errors)) if errors else None,
            "rmse_shown_max": float(np.max(errors)) if errors else None,
            "judged_frames": len(errors)}


# ------------------------------------------------------------------ one run

def wait_for(path: Path, deadline: float, what: str, log) -> None:
    while not path.exists():
        if (path.parent / "failed").exists():
            raise SystemExit(f"the notebook failed: {(path.parent / 'failed').read_text()}")
        if time.monotonic() > deadline:
            raise SystemExit(f"no {what} in time; JupyterLab's log ends:\n{log()}")
        time.sleep(0.05)
    time.sleep(0.1)


def press(driver, mode: str, presses: int) -> None:
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    view = driver.find_element(By.CSS_SELECTOR, VIEW_CSS[mode])
    ActionChains(driver).move_to_element(view).click().perform()  # the view has the focus
    time.sleep(0.5)
    for _ in range(presses):
        ActionChains(driver).key_down("w").pause(0.2).key_up("w").perform()
        time.sleep(0.4)
    time.sleep(1.5)  # the last press's frames


def one_run(driver, base: str, token: str, root: Path, mode: str, args,
            raw: Path | None = None) -> dict:
    name = write_notebook(root, mode, args)
    for f in ("warm", "timed", "pressed", "result.json", "failed", "judge", "judged",
              "judged.npz"):
        (root / f).unlink(missing_ok=True)
    log = lambda: (root / "jupyterlab.log").read_text()[-3000:]  # noqa: E731
    deadline = time.monotonic() + args.deadline
    # a workspace of its own (no tab of an earlier run restored), this notebook current
    driver.get(f"{base}/lab/workspaces/{mode}-{int(time.time())}/tree/{name}?reset&token={token}")
    state = ("const w = window.jupyterapp && window.jupyterapp.shell.currentWidget;"
             f"if (!w || !w.context || w.context.path !== {name!r}) return 'not open';"
             "const k = w.sessionContext && w.sessionContext.session"
             " && w.sessionContext.session.kernel; return k ? k.status : 'none';")
    while driver.execute_script(state) != "idle":
        if time.monotonic() > deadline:
            raise SystemExit(f"the kernel never became idle; {log()}")
        time.sleep(0.2)
    origin = driver.execute_script(RECORDER_JS)
    driver.execute_script("window.jupyterapp.commands.execute('notebook:run-all-cells')")
    page: dict = {"origin_ms": origin}
    wait_for(root / "warm", deadline, "warm-up", log)
    if mode == "sprite":
        page["timed"] = driver.execute_async_script(SPRITE_TIMED_JS)
    wait_for(root / "timed", deadline, "timed path", log)
    press(driver, mode, args.presses)
    if mode == "sprite":
        page["after"] = driver.execute_script(SPRITE_STATS_JS)
    page["rec"] = driver.execute_script("return window.__rec;")
    (root / "pressed").write_text("1")
    wait_for(root / "result.json", deadline, "result", log)
    result = json.loads((root / "result.json").read_text())
    if mode == "sprite":  # the judged pass: the page keeps the sampled frames' pixels
        driver.execute_script(f"{API_JS}.capture(arguments[0]);",
                              list(range(0, args.frames, args.judge_every)))
    (root / "judge").write_text("1")
    wait_for(root / "judged", deadline, "judged pass", log)
    shown = (page_frames(driver.execute_script(f"return {API_JS}.captured();"))
             if mode == "sprite" else stream_frames(root / "judged.npz"))
    driver.execute_async_script(SHUTDOWN_JS)  # this run's kernel ends before the next
    if raw is not None:  # the logs the figures come from, beside them
        raw.write_text(json.dumps({"kernel": result, "page": page}))
    if raw is not None and shown:  # the middle judged frame: shown | reference
        _, vp, image = shown[len(shown) // 2]
        from lodsprite.files import write_png

        write_png(raw.with_suffix(".png"), np.concatenate([image, reference(args, vp)], 1))
    return {**figures(mode, result, page, args), **judge(shown, args)}


def proxy_main(listen: int, target: int, delay_ms: float) -> None:
    """The delay proxy's process: ``listen`` -> ``target`` on 127.0.0.1."""
    from web_vs_streaming import DelayProxy

    async def serve() -> None:
        await DelayProxy(listen, ("127.0.0.1", target), delay_ms / 1e3).start()
        await asyncio.Event().wait()

    asyncio.run(serve())


def start_proxy(listen: int, target: int, rtt_ms: float) -> subprocess.Popen:
    """A delay proxy process holding ``rtt_ms / 2`` each way; returns once it listens."""
    proc = subprocess.Popen([sys.executable, str(HERE), "--role", "proxy",
                             "--listen", str(listen), "--target", str(target),
                             "--delay-ms", str(rtt_ms / 2)])
    deadline = time.monotonic() + 30
    while True:
        try:
            socket.create_connection(("127.0.0.1", listen), timeout=0.5).close()
            return proc
        except OSError:
            if proc.poll() is not None or time.monotonic() > deadline:
                proc.kill()
                raise SystemExit("the delay proxy did not start") from None
            time.sleep(0.1)


# ------------------------------------------------------------------ the command

def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--latencies", default="0,50,150",
                    help="added round trips between page and kernel, ms (comma-separated)")
    ap.add_argument("--terrain", default="jacksboro", help="a DEM, store or built-in")
    ap.add_argument("--size", default="640x480", help="the view, WxH pixels")
    ap.add_argument("--path", default="chen1999", help="the camera path")
    ap.add_argument("--frames", type=int, default=240, help="the path's viewpoints")
    ap.add_argument("--grid", type=int, default=None, help="resample the terrain to N")
    ap.add_argument("--lod", type=int, default=None, help="the sprite widget's coarse LOD")
    ap.add_argument("--epsilon", type=float, default=1.0,
                    help="the sprite widget's error bound, pixels")
    ap.add_argument("--presses", type=int, default=8, help="key presses for input to frame")
    ap.add_argument("--widgets", default="sprite,rfb", help="which widgets, in this order")
    ap.add_argument("--judge-every", type=int, default=8,
                    help="judge the shown image of every n-th path frame (untimed pass)")
    ap.add_argument("--deadline", type=float, default=900.0, help="seconds for one run")
    ap.add_argument("--quick", action="store_true",
                    help="a small run: fractal:128, 320x240, 60 frames, 0 and 150 ms, 3 presses")
    ap.add_argument("--json", type=Path, default=None,
                    help="write the figures here, and beside them each run's logs and "
                         "its middle judged frame beside the reference (PNG)")
    ap.add_argument("--plot", type=Path, default=None, help="draw the figures here (PNG)")
    ap.add_argument("--role", choices=("main", "proxy"), default="main", help=argparse.SUPPRESS)
    ap.add_argument("--listen", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--target", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--delay-ms", type=float, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.quick:
        args.terrain, args.size, args.frames, args.presses = "fractal:128:4", "320x240", 60, 3
        args.latencies = "0,150"
    try:
        args.latencies = [float(v) for v in str(args.latencies).split(",")]
        args.size = tuple(int(v) for v in args.size.lower().split("x"))
        if len(args.size) != 2 or min(args.size) < 16 or min(args.latencies) < 0:
            raise ValueError
    except ValueError:
        ap.error("--size is WxH (at least 16) and --latencies non-negative numbers")
    args.widgets = [w for w in args.widgets.split(",") if w]
    if not args.widgets or set(args.widgets) - set(MODES):
        ap.error(f"--widgets is a comma-separated list of {', '.join(MODES)}")
    if args.frames < 2 or args.presses < 1 or args.judge_every < 1:
        ap.error("--frames at least 2, --presses and --judge-every at least 1")
    return args


COLUMNS = ("frame_ms_median", "frame_ms_p99", "input_to_frame_ms", "input_to_frame_ms_p99",
           "error_px_mean", "rmse_shown", "frames", "keyframes", "inputs", "judged_frames")


def show(rows: list[dict]) -> None:
    def cell(v):
        return "-" if v is None else (f"{v:.1f}" if isinstance(v, float) else str(v))

    head = ["rtt_ms", "widget", *COLUMNS]
    print("  ".join(head))
    for r in rows:
        print("  ".join(cell(r.get(k)) for k in head))


def targets(rows: list[dict], epsilon: float) -> None:
    """The issue's targets, from the figures measured above."""
    for r in rows:
        if r["widget"] != "sprite" or r["frame_ms_median"] is None:
            continue
        p99 = r["frame_ms_p99"] / r["frame_ms_median"]
        inp = (r["input_to_frame_ms"] or float("nan")) / r["frame_ms_median"]
        err = (r["error_px_mean"] or float("nan")) / epsilon
        print(f"sprite at {r['rtt_ms']:g} ms: p99 = {p99:.2f} x median (target <= 2), input to "
              f"frame = {inp:.2f} frame times (target: one), mean shown error = {err:.2f} "
              f"epsilon (target <= 2 along chen1999)")


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for mode, colour in zip(MODES, ("tab:blue", "tab:orange"), strict=True):
        rs = [r for r in rows if r["widget"] == mode]
        x = [r["rtt_ms"] for r in rs]
        for ax, key in zip(axes, ("frame_ms", "input_to_frame_ms"), strict=True):
            med = [r[f"{key}_median" if key == "frame_ms" else key] for r in rs]
            p99 = [r[f"{key}_p99"] for r in rs]
            ax.plot(x, med, "o-", color=colour, label=f"{mode} median")
            ax.plot(x, p99, "s--", color=colour, label=f"{mode} p99")
    for ax, title in zip(axes, ("frame time (ms)", "input to frame (ms)"), strict=True):
        ax.set_xlabel("added round trip, page to kernel (ms)")
        ax.set_title(title)
        ax.set_yscale("log")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.role == "proxy":
        proxy_main(args.listen, args.target, args.delay_ms)
        return
    from lab_fixtures import free_port, jupyterlab

    from browsers import quit_browser, start_browser

    rows = []
    with tempfile.TemporaryDirectory(prefix="notebook-vs-rfb-") as tmp:
        root = Path(tmp)
        with jupyterlab(root, 120.0) as (base, token):
            lab_port = int(base.rsplit(":", 1)[1])
            driver, profile = start_browser(args.deadline, (1280, 1000))
            try:
                for rtt in args.latencies:
                    port = free_port()
                    proxy = start_proxy(port, lab_port, rtt)
                    try:
                        for mode in args.widgets:
                            raw = (None if args.json is None else args.json.with_name(
                                f"{args.json.stem}_{mode}_{rtt:g}ms.json"))
                            fig = one_run(driver, f"http://127.0.0.1:{port}", token, root,
                                          mode, args, raw)
                            rows.append({"rtt_ms": rtt, "widget": mode, **fig})
                            print(f"rtt {rtt:g} ms, {mode}: {json.dumps(fig)}", flush=True)
                    finally:
                        proxy.terminate()
                        proxy.wait(timeout=10)
            finally:
                quit_browser(driver, profile)
                if "ctx" in _REFERENCE:  # the reference's GL objects released
                    _REFERENCE.pop("ctx").__exit__(None, None, None)
    print(f"\n{args.terrain}, {args.size[0]}x{args.size[1]}, {args.path} "
          f"{args.frames} frames, epsilon {args.epsilon:g} px, {args.presses} presses")
    show(rows)
    targets(rows, args.epsilon)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    if args.plot:
        plot(rows, args.plot)


if __name__ == "__main__":
    main()
