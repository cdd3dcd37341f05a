"""The web page as a user runs it: ``lodsprite serve --web`` with ``--renderers`` renderer
processes and a real headless Chromium (SwiftShader WebGL2, driven by selenium through the
system chromedriver) playing a path over a scene, a terrain store or a scene file.

Timed, as the page measures itself (``window.lodsprite.stats()``): the first keyframe
after the page sent ``load``, the keyframe latency median (request to keyframe shown),
the frame interval median and p99 (fps shown), the mean of the page's own error
estimate over the frames drawn, the keyframes shown; and the server's figures (its
renderers' busy seconds).

Judged after the run, untimed: every ``--judge``-th path frame's pixels, captured by the
page as it drew them (``capture``), against a reference of the same viewpoint:

* a terrain or a store: the band-limited level 0 (``harness.scene_reference``, its own
  code path) and, beside it, ``render --mode adaptive``'s image of that viewpoint (the
  adaptive technique, its view's tiles settled first) against the same reference: the
  page's RMSE over the adaptive renderer's says whether the page shows level-0 detail;
* a scene file: lodsprite's full-detail render (``Renderer.draw``: every object at its
  full mesh, the walkers at the time the page drew them).

    python benchmarks/served_pages.py --data /tmp/data --scene f16k.zarr --size 640x480 \\
        --renderers 2 --path chen1999 --frames 240 [--judge 40] [--out DIR]

Writes ``pages.json`` and each judged frame beside its reference (``frame_K.png``) to
``--out`` (default a temporary folder) and prints the figures.
"""

from __future__ import annotations

import argparse
import base64
import json
import queue
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

TOKEN = "served-pages-benchmark"


def start_server(args) -> tuple[subprocess.Popen, int]:
    from lodsprite.distributed.run import free_ports

    proc = subprocess.Popen(
        [sys.executable, "-c", "from lodsprite.cli import main; main()", "serve", "--web",
         "127.0.0.1:0", "--bind", f"127.0.0.1:{free_ports()}", "--token", TOKEN,
         "--rate", "100000", "--renderers", str(args.renderers), "--data", str(args.data),
         "--session-jobs", str(args.session_jobs)],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in proc.stdout], daemon=True).start()
    line = lines.get(timeout=120)
    if not line.startswith("web page: http://127.0.0.1:"):
        raise SystemExit(f"the server did not start: {line}")
    return proc, int(line.split(":")[3].split("/")[0])


def start_browser():
    """The headless Chromium the browser benchmarks share (``web_vs_streaming.browser``),
    with room for a long path."""
    from web_vs_streaming import browser

    driver, profile = browser()
    driver.set_script_timeout(1800)
    return driver, profile


def play(driver, port: int, args) -> dict:
    """Open the page, capture every ``--judge``-th path frame, wait until the path is
    played and its held view's keyframe shown; the page's and the server's figures."""
    w, h = args.size
    query = (f"token={TOKEN}&scene={args.scene}&size={w}x{h}&path={args.path}"
             f"&frames={args.frames}&lod={args.lod}{'&' + args.query if args.query else ''}")
    driver.get(f"http://127.0.0.1:{port}/?{query}")
    picks = list(range(args.judge // 2, args.frames, args.judge))
    return driver.execute_async_script("""
        const [picks, done] = arguments;
        const wait = () => {
          if (!window.lodsprite) { setTimeout(wait, 10); return; }
          window.lodsprite.capture(picks);
          window.lodsprite.ready.then(() => window.lodsprite.finished)
            .then(() => window.lodsprite.serverStats())
            .then((server) => done({stats: window.lodsprite.stats(), server,
                                    captured: window.lodsprite.captured()}),
                  (e) => done({error: String(e)}));
        };
        wait();""", picks)


def frames_of(captured: list) -> list[tuple[int, object, float, np.ndarray]]:
    """(path index, viewpoint, walk time, (h, w, 3) uint8 top-down) of each capture."""
    from lodsprite.camera import Viewpoint

    out = []
    for c in captured:
        rgba = np.frombuffer(base64.b64decode(c["rgba"]), np.uint8)
        image = rgba.reshape(c["height"], c["width"], 4)[::-1, :, :3]  # readPixels: bottom-up
        vp = Viewpoint(*(np.asarray(c["vp"][a], np.float64) for a in "xyzo"))
        out.append((c["index"], vp, float(c.get("t") or 0.0), image))
    return out


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)))


def judge(args, frames: list, out: Path | None = None) -> dict:
    """The captured frames' RMSE against the reference (module doc), untimed; with
    ``out``, each page frame beside its reference as ``frame_K.png``."""
    import imageio.v3 as iio

    def keep(k: int, image: np.ndarray, ref: np.ndarray) -> None:
        if out is not None:
            iio.imwrite(out / f"frame_{k}.png", np.concatenate([image, ref], axis=1))

    from lodsprite import techniques
    from lodsprite.api import Renderer
    from lodsprite.distributed.served import is_object_scene, open_object_scene
    from lodsprite.harness import scene_reference
    from lodsprite.scene.kinds import open_scene

    local = args.data / args.scene  # a file or store under --data, else a built-in
    spec = str(local) if local.exists() else args.scene
    objects = is_object_scene(spec)  # a scene file or a crowd: judged by Renderer.draw
    scene = (open_object_scene(spec, str(args.data)) if objects else
             open_scene(spec, light=True, root=args.data))
    size = tuple(args.size)
    res: dict = {"frames": [f[0] for f in frames]}
    r = Renderer(scene, size, 45.0)  # the page's field of view (the load's default)
    try:
        if objects:
            page = []
            for k, vp, t, image in frames:
                r.draw(vp, t)
                ref = r.read_color()
                keep(k, image, ref)
                page.append(rmse(image, ref))
            res.update(reference="full-detail render (Renderer.draw)", page_rmse=page)
            return res
        with scene_reference(r) as reference:
            refs = [reference(vp) for _, vp, _, _ in frames]
        adaptive = techniques.create("adaptive", r)
        own = []
        try:
            for (_, vp, _, _), ref in zip(frames, refs, strict=True):
                adaptive.warm_up(vp)
                adaptive.frame(vp)
                r.gl.finish()
                own.append(rmse(r.read_color(), ref))
        finally:
            adaptive.release()
        page = []
        for (k, _, _, image), ref in zip(frames, refs, strict=True):
            keep(k, image, ref)
            page.append(rmse(image, ref))
        res.update(reference="band-limited level 0 (harness.scene_reference)",
                   page_rmse=page, adaptive_rmse=own,
                   page_over_adaptive=float(np.mean(page) / np.mean(own)))
        return res
    finally:
        r.release()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True, help="the server's --data folder")
    ap.add_argument("--scene", required=True, help="a name under --data: a store, a DEM, "
                                                   "a scene file; or crowd:N")
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--renderers", type=int, default=2)
    ap.add_argument("--session-jobs", type=int, default=1,
                    help="the server's --session-jobs: the page's requests in flight")
    ap.add_argument("--path", default="chen1999")
    ap.add_argument("--frames", type=int, default=240)
    ap.add_argument("--lod", type=int, default=16)
    ap.add_argument("--judge", type=int, default=40, help="judge every N-th path frame")
    ap.add_argument("--query", default="", help="more of the page's query string, e.g. "
                                                "proxy=geometry&keyscale=1")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    args.size = [int(v) for v in args.size.split("x")]
    args.data = args.data.resolve()
    out = args.out or Path(tempfile.mkdtemp(prefix="served-pages-"))
    out.mkdir(parents=True, exist_ok=True)
    proc, port = start_server(args)
    driver = profile = None
    try:
        driver, profile = start_browser()
        t0 = time.perf_counter()
        got = play(driver, port, args)
        wall = time.perf_counter() - t0
    finally:
        if driver is not None:
            driver.quit()
            shutil.rmtree(profile, ignore_errors=True)
        proc.terminate()
        proc.wait(timeout=30)
    if "error" in got:
        raise SystemExit(f"the page failed: {got['error']}")
    s, server = got["stats"], got["server"]
    frames = frames_of(got["captured"])
    judged = judge(args, frames, out)
    record = {"scene": args.scene, "query": args.query, "size": args.size,
              "renderers": args.renderers, "path": args.path, "frames": args.frames,
              "lod": args.lod, "wall_s": wall,
              "page": s, "session": server["session"], "pool": server["server"]["pool"],
              "judged": judged}
    (out / "pages.json").write_text(json.dumps(record, indent=1))
    fps = 1e3 / s["median_ms"] if s["median_ms"] else float("nan")
    print(f"{args.scene} at {args.size[0]}x{args.size[1]}, {args.renderers} renderers, "
          f"{args.path} {args.frames} frames (Chromium, SwiftShader)")
    print(f"  first keyframe {s['first_keyframe_ms'] / 1e3:.2f} s after load; keyframe "
          f"latency median {s['latency_ms'] / 1e3:.2f} s; {s['keyframes']} keyframes shown")
    way = [(k, s.get(f"first_{k}_ms")) for k in ("scene", "request", "arrived")]
    print("    on the way: " + ", ".join(f"{k} {v / 1e3:.2f} s" for k, v in way if v is not None)
          + f"; key scale {s.get('key_scale')}")
    print(f"  frames: median {s['median_ms']:.1f} ms ({fps:.1f} fps), p99 {s['p99_ms']:.1f} ms;"
          f" estimate mean {s['error_px_mean']:.2f} px")
    print(f"  renderers busy {server['server']['pool'].get('busy_s', float('nan')):.1f} s "
          f"of {wall:.1f} s; keyframes {server['session'].get('keyframes')}")
    print(f"  judged {len(frames)} frames against {judged['reference']}: page RMSE mean "
          f"{np.mean(judged['page_rmse']):.2f}", end="")
    if "adaptive_rmse" in judged:
        print(f", render --mode adaptive {np.mean(judged['adaptive_rmse']):.2f} "
              f"(page / adaptive {judged['page_over_adaptive']:.2f})")
    else:
        print()
    print(f"  written: {out / 'pages.json'}")


if __name__ == "__main__":
    main()
