"""Benchmark: where a spriteframe loses the keyframe's detail, part by part.

On a terrain store along a path, at keyframes spread over the path, each image is judged
against the band-limited level 0 at its own viewpoint
(:class:`~lodsprite.gl.reference.LevelZeroReference`, 4 x 4 samples a pixel, box, linear
light), and the figures are RMSE (grey levels) means over the keyframes:

* ``keyframe``: the keyframe itself (the adaptive renderer at ``key_sse``), guard band cut;
* ``still``: the spriteframe drawn at the keyframe's own viewpoint (projective texturing is
  exact there for any proxy: what is lost comes from silhouettes and the visibility rule);
* ``rot D``: the spriteframe at the keyframe's eye turned by ``D`` pixels about the view's
  vertical axis (no parallax: resampling alone, and silhouettes), and beside it the
  keyframe drawn at that turned view (``key rot D``: what a new keyframe would score);
* ``move N``: the eye moved along the path's direction by ``N`` frames' travel, the view
  direction kept (parallax), for each variant's proxy: today's (the store's defaults:
  the view-dependent proxy at ``proxy_sse``) and the keyframe's own geometry (the
  adaptive mesh at ``key_sse``);
* ``path N``: the path's own frame ``N`` after the keyframe (turn and travel together), as
  LOD-sprite would draw it from that keyframe;
* ``band``: the silhouette band: pixels (of the image, guard band cut) where the proxy's
  z-buffer and the keyframe's disagree at the keyframe's view: one sees sky and the other
  ground, or their depths differ by more than the ``coarse`` rule's tolerance.

Each variant is a line of ``--variant NAME:OPTION=VALUE,...`` (technique options of
``sprite-adaptive`` over the store's defaults); default: ``today`` and ``fullproxy``.

    python benchmarks/sprite_decomposition.py --terrain STORE [--path flyover]
        [--frames 120] [--size 512] [--keys 4] [--out DIR]

Writes ``decomposition.json`` and ``decomposition.png`` (the error of each part against
the keyframe's) to ``--out`` when given.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from lodsprite import techniques
from lodsprite.api import Renderer
from lodsprite.bandlimit import downsample
from lodsprite.camera import Viewpoint, turned
from lodsprite.experiments.large.runs import sprite_lod
from lodsprite.gl.reference import LevelZeroReference
from lodsprite.gl.sprite import DEFAULT_COARSE_TOL
from lodsprite.metrics import rmse
from lodsprite.run import RenderConfig, prepare
from lodsprite.techniques.adaptive import scene_pyramid
from lodsprite.techniques.defaults import STORE_DEFAULTS

TURNS = (0.25, 0.5, 1.0, 2.0, 3.0)  # pixels at the image centre
MOVES = (1, 2, 4, 8)               # frames of the path's travel
DEFAULT_VARIANTS = ("today:", "fullproxy:proxy_sse=KEY")


def moved(vp: Viewpoint, step: np.ndarray) -> Viewpoint:
    return Viewpoint(vp.x, vp.y, vp.z, vp.o + step)


def linear_depth(z: np.ndarray, near: float, far: float) -> np.ndarray:
    """Eye distance (metres) of window depths ``z`` in [0, 1] (inf where 1: sky)."""
    ndc = 2.0 * z.astype(np.float64) - 1.0
    with np.errstate(divide="ignore"):
        d = 2.0 * near * far / (far + near - ndc * (far - near))
    return np.where(z >= 1.0, np.inf, d)


def silhouette_band(sprite) -> int:
    """Pixels (guard band cut) where the keyframe's z-buffer and its proxy's disagree."""
    key = sprite.keyframe
    g = sprite.guard_px
    k = np.asarray(key.target.read_depth())
    c = np.asarray(key.coarse.read_depth())
    h, w = k.shape
    k, c = k[g:h - g, g:w - g], c[g:h - g, g:w - g]
    near, far = key.projection.near, key.projection.far
    dk, dc = linear_depth(k, near, far), linear_depth(c, near, far)
    sky = np.isinf(dk) != np.isinf(dc)
    both = np.isfinite(dk) & np.isfinite(dc)
    rel = np.zeros_like(dk)
    rel[both] = np.abs(dk[both] - dc[both]) / dk[both]
    return int(np.count_nonzero(sky | (rel > 10 * DEFAULT_COARSE_TOL)))


def error(image: np.ndarray | None, reference: np.ndarray) -> float:
    return float("nan") if image is None else rmse(image, reference)


def parse_variant(text: str, key_sse: float) -> tuple[str, dict]:
    name, _, rest = text.partition(":")
    opts: dict = {}
    for item in filter(None, rest.split(",")):
        k, _, v = item.partition("=")
        if v == "KEY":
            opts[k] = key_sse
            continue
        for cast in (int, float):
            try:
                opts[k] = cast(v)
                break
            except ValueError:
                continue
        else:
            opts[k] = {"true": True, "false": False}.get(v.lower(), v)
    return name, opts


class Case:
    """One variant's technique on the renderer, driven keyframe by keyframe."""

    def __init__(self, renderer: Renderer, options: dict) -> None:
        self.tech = techniques.create("sprite-adaptive", renderer, **options)
        self.sprite = self.tech.sprite.sprite
        self.target = self.sprite.target

    def keyframe(self, vp: Viewpoint) -> np.ndarray:
        s = self.sprite
        self.tech.adaptive.fill(vp, s.key_projection(s.terrain.projection(vp)).matrix())
        s.render_keyframe(vp, 0.0)
        img = s.keyframe_color()
        if s.key_scale == 1.0:
            return img
        if s.key_scale == 2.0:  # its texels resolved as the reference's: box, linear light
            return downsample(img, 2)
        return None  # no whole-texel box at this scale

    def spriteframe(self, vp: Viewpoint) -> np.ndarray:
        self.sprite.render_spriteframe(vp)
        return self.target.read_color()

    def release(self) -> None:
        self.tech.release()


def measure(args: argparse.Namespace) -> dict:
    size = (args.size, args.size)
    scene, path = prepare(RenderConfig(terrain=args.terrain, path=args.path,
                                       frames=args.frames, mode="sprite", size=size))
    fov = path.fov_y_deg
    base = {k: v for k, v in STORE_DEFAULTS.items() if v is not None}
    base["key_sse"] = args.key_sse
    pyramid = scene_pyramid(scene)
    base["lod"] = sprite_lod(max(pyramid.shape(0)))
    variants = [parse_variant(v, args.key_sse) for v in (args.variant or DEFAULT_VARIANTS)]
    n = len(path.viewpoints)
    keys = [int(n * (j + 0.5) / args.keys) for j in range(args.keys)]
    keys = [i for i in keys if i + max(MOVES) < n]
    out: dict = {"terrain": args.terrain, "path": args.path, "size": args.size,
                 "key_sse": args.key_sse, "keys": keys, "variants": {}}
    with Renderer(scene, size, fov) as renderer:
        ref = LevelZeroReference(renderer.gl, pyramid, size, fov, "heights")
        refs: dict = {}

        def reference(tag, vp):
            if tag not in refs:
                refs[tag] = ref.image(vp)
            return refs[tag]

        out["renderer"] = renderer.info.renderer
        out["reference"] = ref.describe()
        try:
            for name, opts in variants:
                t0 = time.perf_counter()
                case = Case(renderer, {**base, **opts})
                rows = []
                try:
                    for i in keys:
                        vp = path.viewpoints[i]
                        r: dict = {"frame": i}
                        r["keyframe"] = error(case.keyframe(vp), reference(("v", i), vp))
                        r["band"] = silhouette_band(case.sprite)
                        r["still"] = rmse(case.spriteframe(vp), reference(("v", i), vp))
                        for d in TURNS:
                            vr = turned(vp, d, args.size, fov)
                            r[f"rot {d:g}"] = rmse(case.spriteframe(vr),
                                                   reference(("r", i, d), vr))
                        step = (path.viewpoints[i + 1].o - vp.o)
                        for m in MOVES:
                            vm = moved(vp, m * step)
                            r[f"move {m}"] = rmse(case.spriteframe(vm),
                                                  reference(("m", i, m), vm))
                        for m in MOVES:
                            vn = path.viewpoints[i + m]
                            r[f"path {m}"] = rmse(case.spriteframe(vn),
                                                  reference(("v", i + m), vn))
                        if opts.get("key_scale", 1.0) == 1.0 and name == variants[0][0]:
                            for d in TURNS:
                                vr = turned(vp, d, args.size, fov)
                                r[f"key rot {d:g}"] = error(case.keyframe(vr),
                                                           reference(("r", i, d), vr))
                        rows.append(r)
                        print(f"  {name} frame {i}: " + ", ".join(
                            f"{k} {v:.2f}" for k, v in r.items() if k != "frame"), flush=True)
                finally:
                    case.release()
                out["variants"][name] = {"options": {**base, **opts}, "rows": rows,
                                         "seconds": time.perf_counter() - t0}
        finally:
            ref.release()
    return out


def table(out: dict) -> str:
    lines = [f"{out['terrain']}, path {out['path']}, {out['size']}² px, keyframes at "
             f"{out['key_sse']:g} px, frames {out['keys']}; {out['renderer']}",
             f"reference: {out['reference']}",
             "mean RMSE (grey levels) against the band-limited level 0; band: pixels"]
    for name, v in out["variants"].items():
        rows = v["rows"]
        cols = [k for k in rows[0] if k != "frame"]
        lines.append(f"\n{name}: {', '.join(f'{k}={o}' for k, o in v['options'].items())}")
        for k in cols:
            vals = [r[k] for r in rows]
            lines.append(f"  {k:12s} {np.mean(vals):9.2f}   "
                         + " ".join(f"{x:8.2f}" for x in vals))
    return "\n".join(lines)


def plot(out: dict, file: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4))
    for name, v in out["variants"].items():
        rows = v["rows"]
        cols = [k for k in rows[0] if k not in ("frame", "band")]
        ax.plot(range(len(cols)), [np.mean([r[k] for r in rows]) for k in cols], "o-",
                label=name)
        ax.set_xticks(range(len(cols)), cols, rotation=60, ha="right", fontsize=8)
    ax.set_ylabel("RMSE against band-limited level 0")
    ax.set_title(f"{Path(out['terrain']).name}, {out['path']}, {out['size']}²")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(file, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--terrain", required=True, help="a terrain store")
    ap.add_argument("--path", default="flyover")
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--keys", type=int, default=4)
    ap.add_argument("--key-sse", type=float, default=STORE_DEFAULTS["key_sse"])
    ap.add_argument("--variant", action="append",
                    help="NAME:OPTION=VALUE,... (KEY: the keyframe tolerance)")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    out = measure(args)
    print(table(out))
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "decomposition.json").write_text(json.dumps(out, indent=1))
        plot(out, args.out / "decomposition.png")


if __name__ == "__main__":
    main()
