"""The web page's spriteframes in motion against lodsprite's own, and its error estimate.

Along a path over a terrain (default the flyover over the real Jacksboro DEM), a server
keyframe (:class:`~lodsprite.distributed.render.KeyframeService`) every ``--every``
viewpoints, and from each the spriteframes ``--offsets`` viewpoints on: drawn by the
page's ``gl.js`` in a real browser (Debian's chromium, headless, SwiftShader WebGL2;
the keyframe crossing as the wire's message, decoded by the page's modules), by the
page's first drawer (its z-buffer sampled nearest, no border ribbons: the test
helper's ``old``), and by lodsprite's own drawer (:class:`~lodsprite.gl.sprite.
SpriteDrawer`, the distributed client's).  Per offset, median and range over the
keyframes of: the RMSE (grey levels) of each page frame against lodsprite's spriteframe
and against the full-resolution render of the viewpoint, lodsprite's spriteframe
against that render, and the page's error estimate (``distributed.web.estimate``, the
keyframe's view-projection given), pixels.

    python benchmarks/web_spriteframes.py [--size 256] [--every 20] [--offsets 3,10,20]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "distributed" / "web"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--terrain", default="jacksboro")
    ap.add_argument("--grid", type=int, default=None)
    ap.add_argument("--lod", type=int, default=16)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--path", default="flyover")
    ap.add_argument("--frames", type=int, default=460)
    ap.add_argument("--every", type=int, default=20)
    ap.add_argument("--offsets", default="3,10,20")
    a = ap.parse_args()
    from spriteframes import offline_spriteframes, page_spriteframes, rmse
    from test_browser import TOKEN, start_browser

    from lodsprite.camera import Projection
    from lodsprite.distributed.protocol import LoadArgs
    from lodsprite.distributed.render import KeyframeService
    from lodsprite.distributed.run import free_ports
    from lodsprite.distributed.web.estimate import ErrorMetric, Predictor
    from lodsprite.distributed.web.scene import build_scene, decode_scene
    from lodsprite.paths import get_path

    offsets = [int(s) for s in a.offsets.split(",")]
    args = LoadArgs(terrain=a.terrain, grid=a.grid, lod=a.lod, size=(a.size, a.size))
    parts = build_scene(args)
    scene = decode_scene(parts)
    h = scene.header
    proj = Projection(h.fov, 1.0, h.near, h.far)  # the page's
    service = KeyframeService(args)
    path = get_path(a.path, service.terrain_gl.scene.hf, a.frames).viewpoints
    starts = range(0, len(path) - max(offsets), a.every)
    keys = [(service.render(path[k], k, 0.0), [path[k + d] for d in offsets]) for k in starts]
    own = offline_spriteframes(service, a.lod, keys, proj)
    full, estimate = [], []
    metric, pred = ErrorMetric(scene), Predictor(scene)
    drawer = service.terrain_gl.drawer
    for kf, vps in keys:
        key_vp = kf.projection.matrix() @ kf.viewpoint.view_matrix()
        for vp in vps:
            drawer.render(vp, None, proj)
            full.append(np.array(drawer.target.read_color())[::-1])
            estimate.append(pred.error_px(metric, kf.viewpoint.o, vp, key_vp))
    service.release()
    drawn = [(kf, [proj.matrix() @ vp.view_matrix() for vp in vps]) for kf, vps in keys]
    server = subprocess.Popen(
        [sys.executable, "-c", "from lodsprite.cli import main; main()", "serve", "--web",
         "127.0.0.1:0", "--bind", f"127.0.0.1:{free_ports()}", "--token", TOKEN],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    browser = None
    try:
        port = int(server.stdout.readline().split(":")[3].split("/")[0])
        browser, _ = start_browser()
        browser.get(f"http://127.0.0.1:{port}/static/hud.js")  # the page's origin
        page = page_spriteframes(browser, parts, drawn, (a.size, a.size))
        first = page_spriteframes(browser, parts, drawn, (a.size, a.size), old=True)
    finally:
        if browser is not None:
            browser.quit()
        server.terminate()
        server.wait(timeout=15)
    def against(a: list, b: list) -> list[float]:
        return [rmse(x, y) for x, y in zip(a, b, strict=True)]

    rows = {"page vs lodsprite's spriteframe": against(page, own),
            "first page vs lodsprite's": against(first, own),
            "page vs full render": against(page, full),
            "first page vs full render": against(first, full),
            "lodsprite's vs full render": against(own, full),
            "page's estimate (px)": estimate}
    print(f"{a.terrain} {a.path}, lod {a.lod}, {a.size}x{a.size}, {len(keys)} keyframes")
    for j, d in enumerate(offsets):
        print(f"{d} viewpoints on from the keyframe: median [min, max]")
        for name, values in rows.items():
            v = np.asarray(values[j::len(offsets)])
            v = v[np.isfinite(v)]
            print(f"  {name:34s} {np.median(v):7.2f} [{v.min():.2f}, {v.max():.2f}]")


if __name__ == "__main__":
    main()
