"""LOD-sprite's defaults are declared once: the Python API (``Renderer.sprite``,
``techniques.create``) and ``render`` draw the same scene with the same options alike, and
an option the chosen technique does not take is refused, never ignored."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import run_cli
from lodsprite import techniques
from lodsprite.api import Renderer, read_image
from lodsprite.errors import InputError
from lodsprite.run import RenderConfig, prepare, render_path
from lodsprite.techniques.defaults import MEMORY_DEFAULTS
from lodsprite.terrain.store import build_store

SIZE = (64, 64)
FRAMES = 12


def api_frames(scene, path, make) -> list[np.ndarray]:
    """The frames shown along ``path`` by the engine ``make(renderer)`` makes."""
    out = []
    with Renderer(scene, SIZE, path.fov_y_deg) as r:
        engine = make(r)
        try:
            for vp in path.viewpoints:
                engine.frame(vp)
                out.append(engine.read_image())
        finally:
            engine.release()
    return out


def low_level(r, options):
    """The API's LOD-sprite with ``options`` (technique options) by hand."""
    depth = options.get("proxy") in ("depth", "search")
    sprite = r.sprite(depth_stride=MEMORY_DEFAULTS["depth_stride"] if depth else None,
                      key_scale=options.get("key_scale", 1.0))
    if options.get("proxy") == "search":
        sprite.sprite.use_search()
    return sprite


@pytest.mark.parametrize("options", [{}, {"proxy": "depth", "key_scale": 2.0},
                                     {"proxy": "search"}])
def test_the_api_and_render_draw_an_in_memory_terrain_alike(tmp_path, options):
    cfg = RenderConfig(terrain="fractal:128:2", mode="sprite", frames=FRAMES, size=SIZE,
                       save_frames=True, **options)
    scene, path = prepare(cfg)
    low = api_frames(scene, path, lambda r: low_level(r, options))
    made = api_frames(scene, path, lambda r: techniques.create("sprite", r, **options))
    render_path(cfg, tmp_path)
    saved = [read_image(tmp_path / "frames" / f"frame_{i:05d}.png") for i in range(FRAMES)]
    for a, b, c in zip(low, made, saved, strict=True):
        assert np.abs(a.astype(int) - b).max() <= 1
        assert np.abs(b.astype(int) - c).max() <= 1


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    path = tmp_path_factory.mktemp("same") / "s.zarr"
    build_store("fractal:256:4", path, tile=128, chunk=64)
    return str(path)


def test_the_api_and_render_draw_a_store_with_the_same_technique_and_options(store,
                                                                               tmp_path):
    # Over a store the sprite technique draws adaptive keyframes with the store's defaults,
    # made by techniques.create as by render (the tiles stream while the path is flown, so
    # the same settings, not the same pixels, are compared).
    cfg = RenderConfig(terrain=store, mode="sprite", frames=4, size=SIZE)
    scene, path = prepare(cfg)
    with Renderer(scene, SIZE, path.fov_y_deg) as r:
        tech = techniques.create("sprite", r)
        try:
            api = tech.summary([])
        finally:
            tech.release()
    run_cli("render", "--terrain", store, "--mode", "sprite", "--frames", "4",
            "--size", "64x64", "--out", str(tmp_path))
    cli = json.loads((tmp_path / "summary.json").read_text())
    assert tech.name == cli["technique"] == "sprite-adaptive"
    for key in ("key_sse", "proxy_sse", "metric", "lod", "proxy", "key_scale"):
        assert api[key] == cli[key], key


def test_an_option_the_technique_does_not_take_is_refused(tmp_path):
    with pytest.raises(InputError, match="--keyframes does not go with --mode adaptive"):
        RenderConfig(terrain="fractal:64", mode="adaptive", keyframes="worker").validate()
    r = run_cli("render", "--terrain", "fractal:64", "--mode", "full", "--epsilon", "2",
                "--frames", "3", "--size", "32x32", "--out", str(tmp_path / "x"))
    assert r.returncode == 2 and "--epsilon does not go with --mode full" in r.stderr
    assert r.stderr.strip().count("\n") == 0 and not (tmp_path / "x").exists()


def test_the_depth_metric_without_the_depth_proxy_is_refused(tmp_path):
    r = run_cli("render", "--terrain", "fractal:64", "--mode", "sprite", "--metric", "depth",
                "--proxy", "geometry", "--frames", "2", "--size", "32x32",
                "--out", str(tmp_path / "x"))
    assert r.returncode == 2 and "--proxy depth" in r.stderr
    assert r.stderr.strip().count("\n") == 0 and not (tmp_path / "x").exists()
