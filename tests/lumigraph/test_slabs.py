"""Six slabs round an object (beyond the paper) and meshes with their own colours."""

from __future__ import annotations

import csv
import json

import numpy as np
import trimesh

from lodsprite.lumigraph.geometry import SIX_DIRECTIONS, facing_slab, slab_facing
from lodsprite.lumigraph.paths import orbit_path
from lodsprite.lumigraph.run import capture_lumigraph, load_object, render_lumigraph
from lodsprite.lumigraph.store import Lumigraph


def test_the_facing_slab_is_the_one_whose_axis_points_at_the_eye():
    slabs = [slab_facing(np.zeros(3), 1.0, d, 4, 16) for d in SIX_DIRECTIONS]
    for k, d in enumerate(SIX_DIRECTIONS):
        eye = 6.0 * d + 0.3 * np.roll(d, 1)        # a little off the axis
        assert facing_slab(slabs, eye) == k


def test_six_slabs_let_a_full_orbit_be_reconstructed(tmp_path):
    s = capture_lumigraph("still-life", tmp_path / "lf", n_st=6, n_uv=48, codec="png",
                          slabs=6)
    assert s["nodes"] == 6 * 36
    header = json.loads((tmp_path / "lf" / "lumigraph.json").read_text())
    axes = np.array([np.asarray(sl["frame"])[:3, 2] for sl in header["slabs"]])
    np.testing.assert_allclose(np.abs(axes @ axes.T), np.eye(6) + np.abs(
        np.kron(np.eye(3), [[0, 1], [1, 0]])), atol=1e-9)   # three opposite pairs
    lf = Lumigraph(tmp_path / "lf")
    path = orbit_path(lf.slabs, 16)
    # the orbit goes all the way round: four of the six slabs face it in turn
    faced = {facing_slab(lf.slabs, vp.o) for vp in path.viewpoints}
    assert len(faced) == 4
    summary = render_lumigraph(tmp_path / "lf", tmp_path / "out", size=(64, 64), path=path,
                               ground_truth=True, method="arbitrary", quality_every=1,
                               nodes=9)
    assert summary["slab_switches"] == 4       # round and back to the first
    # a switch (the next slab's method made and filled) is part of its frame's time
    kinds = [r.split(",")[1] for r in
             (tmp_path / "out" / "frames.csv").read_text().splitlines()[1:]]
    assert kinds.count("switch") == 4
    # a coarse 6x6 lumigraph per side, yet the orbit resembles the object all round
    with (tmp_path / "out" / "frames.csv").open() as f:
        psnr = [float(r["psnr"]) for r in csv.DictReader(f)]
    assert min(psnr) > 15.0, psnr


def test_a_mesh_brings_its_vertex_or_texture_colours(tmp_path):
    red = trimesh.creation.icosphere(2)
    red.visual.vertex_colors = np.tile([255, 0, 0, 255], (len(red.vertices), 1))
    red.export(tmp_path / "red.ply")
    from PIL import Image

    box = trimesh.creation.box()
    uv = np.random.default_rng(0).uniform(0, 1, (len(box.vertices), 2))
    box.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.new("RGB", (8, 8),
                                                                      (0, 200, 0)))
    box.export(tmp_path / "green.glb")
    np.testing.assert_allclose(load_object(str(tmp_path / "red.ply")).colors, [[1, 0, 0]] *
                               len(red.vertices))
    green = load_object(str(tmp_path / "green.glb")).colors
    np.testing.assert_allclose(green, np.tile([0, 200 / 255, 0], (len(green), 1)), atol=1e-6)
    # and the captured node images show it: the sphere fills the middle of the uv image
    capture_lumigraph(str(tmp_path / "red.ply"), tmp_path / "lf", n_st=2, n_uv=32,
                      codec="png")
    img = Lumigraph(tmp_path / "lf").node(0, 0, 0)
    centre = img[12:20, 12:20].astype(float)
    assert (centre[..., 0] > 2 * centre[..., 1] + 20).all()
