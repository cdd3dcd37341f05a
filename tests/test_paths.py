"""Tests of lodsprite.paths: the Chen 1999 / Swan 2002 paths and the JSON path format."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from lodsprite.camera import look_at
from lodsprite.errors import PathError
from lodsprite.paths import (
    CameraPath,
    chen1999,
    get_path,
    load_path_json,
    swan2002,
)
from lodsprite.terrain.heightfield import HeightField

L = 10_000.0


def _field(n: int = 129, ridge_angle_deg: float = 0.0, height: float = 1500.0) -> HeightField:
    """A ``n x n`` field of side ``L``: a Gaussian ridge through the centre amid flat plains.

    The ridge runs along ``ridge_angle_deg`` from north (0 = a north-south ridge);
    the plains carry a few metres of ripple.
    """
    xs = np.linspace(-L / 2, L / 2, n)
    x, y = np.meshgrid(xs, xs[::-1])  # row 0 is north
    a = math.radians(ridge_angle_deg)
    across = x * math.cos(a) - y * math.sin(a)
    along = x * math.sin(a) + y * math.cos(a)
    h = height * np.exp(-((across / (0.07 * L)) ** 2 + (along / (0.3 * L)) ** 2))
    h += 3.0 * np.sin(x / 310.0) * np.cos(y / 270.0) + 100.0
    return HeightField(h.astype(np.float32), L / (n - 1), L / (n - 1), name="ridge")


@pytest.fixture(scope="module")
def hf() -> HeightField:
    return _field()


@pytest.fixture(scope="module")
def chen(hf: HeightField) -> CameraPath:
    return chen1999(hf)


@pytest.fixture(scope="module")
def swan(hf: HeightField) -> CameraPath:
    return swan2002(hf)


def _target(hf: HeightField) -> np.ndarray:
    return np.array([0.0, 0.0, float(hf.height_at(0.0, 0.0))])


def _dist_to_polyline(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Distance (metres) of each of ``points (M, 3)`` to the polyline ``poly (K, 3)``."""
    a, b = poly[:-1], poly[1:]
    ab = b - a
    t = np.einsum("mki,ki->mk", points[:, None, :] - a[None], ab) / np.einsum("ki,ki->k", ab, ab)
    t = np.clip(t, 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(points[:, None, :] - closest, axis=2).min(axis=1)


def _assert_valid_axes(path: CameraPath) -> None:
    ax = path.axes()
    assert np.all(np.isfinite(ax)) and np.all(np.isfinite(path.eyes()))
    np.testing.assert_allclose(ax @ np.transpose(ax, (0, 2, 1)),
                               np.broadcast_to(np.eye(3), ax.shape), atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(ax), 1.0, atol=1e-9)


# --------------------------------------------------------------------------- chen1999


@pytest.mark.parametrize("n", [2, 115, 921])
def test_chen_frame_counts(hf: HeightField, n: int) -> None:
    assert len(chen1999(hf, n)) == n


def test_chen_key_frames(hf: HeightField, chen: CameraPath) -> None:
    assert len(chen) == 460 and chen.name == "chen1999" and chen.fov_y_deg == 45.0
    target = _target(hf)
    rel = chen.eyes() - target
    dist = np.linalg.norm(rel, axis=1)
    elev = np.degrees(np.arcsin(rel[:, 2] / dist))
    azim = np.degrees(np.arctan2(rel[:, 1], rel[:, 0]))
    np.testing.assert_allclose(rel[0], [0.0, 0.0, 1.5 * L], atol=1e-6)
    # Screen-up at the zenith is north: the camera will come down on the south side.
    np.testing.assert_allclose(chen.viewpoints[0].y, [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(elev[:100], np.linspace(90.0, 10.0, 100), atol=1e-9)
    np.testing.assert_allclose(azim[1:100], -90.0, atol=1e-9)
    np.testing.assert_allclose(elev[99:], 10.0, atol=1e-9)
    np.testing.assert_allclose(dist[:380], 1.5 * L, rtol=1e-12)
    assert azim[100] > -90.0 and azim[99] == pytest.approx(-90.0)
    assert azim[379] == pytest.approx(180.0)
    np.testing.assert_allclose(dist[379:], np.linspace(1.5 * L, 0.4 * L, 81), rtol=1e-12)
    assert dist[-1] == pytest.approx(0.4 * L, rel=1e-12)


@pytest.mark.parametrize("n", [115, 460, 1840])
def test_chen_looks_at_target_with_orthonormal_axes(hf: HeightField, n: int) -> None:
    path = chen1999(hf, n)
    _assert_valid_axes(path)
    to_target = _target(hf) - path.eyes()
    to_target /= np.linalg.norm(to_target, axis=1, keepdims=True)
    fwd = np.stack([v.forward for v in path.viewpoints])
    np.testing.assert_allclose(np.einsum("ni,ni->n", fwd, to_target), 1.0, atol=1e-12)
    # Screen-up never points down and changes continuously (no flip at the zenith).
    up = path.axes()[:, 1]
    assert up[:, 2].min() > -1e-12
    assert np.einsum("ni,ni->n", up[1:], up[:-1]).min() > 0.99


def test_chen_continuity(chen: CameraPath) -> None:
    steps = np.linalg.norm(np.diff(chen.eyes(), axis=0), axis=1)
    for seg in (steps[:99], steps[99:379], steps[379:]):
        assert seg.max() < 3.0 * np.median(seg)
        assert seg.min() > 0.0
    # Uniform speed within each segment.
    for seg in (steps[:99], steps[99:379], steps[379:]):
        np.testing.assert_allclose(seg, seg.mean(), rtol=1e-6)


def test_chen_more_frames_same_curve(hf: HeightField, chen: CameraPath) -> None:
    dense = chen1999(hf, 920)
    off = _dist_to_polyline(dense.eyes(), chen.eyes())
    assert off.max() < 1e-4 * L  # chord sagitta of the 460-frame polyline
    np.testing.assert_allclose(dense.eyes()[[0, -1]], chen.eyes()[[0, -1]], atol=1e-9)


def test_frames_must_be_at_least_two(hf: HeightField) -> None:
    for bad in (1, 0, -5, 2.5, True):
        with pytest.raises(PathError):
            chen1999(hf, bad)
        with pytest.raises(PathError):
            swan2002(hf, bad)


# --------------------------------------------------------------------------- swan2002


@pytest.mark.parametrize("n", [2, 150])
def test_swan_frame_counts(hf: HeightField, n: int) -> None:
    assert len(swan2002(hf, n)) == n


def _check_swan(hf: HeightField, path: CameraPath, peak_xy: np.ndarray) -> None:
    eyes = path.eyes()
    n = len(path)
    _assert_valid_axes(path)
    lo, hi = hf.bounds()
    # Starts outside the terrain, far from it, high up.
    gap = np.maximum(0.0, np.maximum(lo[:2] - eyes[0, :2], eyes[0, :2] - hi[:2]))
    assert np.linalg.norm(gap) > 0.5 * hf.extent
    assert eyes[0, 2] > hi[2] + 0.5 * hf.extent
    # Passes over the range's peak.
    horiz = np.linalg.norm(eyes[:, :2] - peak_xy, axis=1)
    assert horiz.min() < 0.01 * hf.extent
    # Always above the terrain with clearance around the ground point.
    rad = 0.02 * hf.extent
    ang = np.linspace(0.0, 2 * np.pi, 24, endpoint=False)
    ring = np.concatenate([[[0.0, 0.0]], np.c_[np.cos(ang), np.sin(ang)] * rad,
                           np.c_[np.cos(ang), np.sin(ang)] * rad / 2])
    pts = eyes[:, None, :2] + ring[None]
    ground = hf.height_at(pts[..., 0], pts[..., 1]).max(axis=1)
    assert np.all(eyes[:, 2] >= ground + 0.02 * hf.extent)
    # The middle of the flight is low: well below the start.
    mid = eyes[int(0.25 * n):int(0.95 * n), 2]
    assert mid.max() < hi[2] + 0.1 * hf.extent
    assert mid.max() - lo[2] < 0.3 * (eyes[0, 2] - lo[2])
    # Over the start plain the eye flies low.
    plain = eyes[int(0.22 * n):int(0.30 * n), 2]
    assert plain.max() - lo[2] < 0.06 * hf.extent
    # Smooth motion: no jumps, step lengths change gradually, no stops.
    steps = np.linalg.norm(np.diff(eyes, axis=0), axis=1)
    assert steps.min() > 0.0
    ratio = steps[1:] / steps[:-1]
    assert ratio.max() < 1.15 and ratio.min() > 0.85
    # Screen-up close to +z; cruise pitched down 15-20 degrees along the heading.
    axes = path.axes()
    assert axes[:, 1, 2].min() > math.cos(math.radians(40.0))
    fwd = -axes[int(0.3 * n):, 2]
    pitch = np.degrees(np.arcsin(-fwd[:, 2]))
    assert np.all((pitch >= 15.0) & (pitch <= 20.0))
    heading = eyes[-1, :2] - eyes[int(0.3 * n), :2]
    heading /= np.linalg.norm(heading)
    flat = fwd[:, :2] / np.linalg.norm(fwd[:, :2], axis=1, keepdims=True)
    assert (flat @ heading).min() > 0.999


def test_swan_flies_over_the_ridge(hf: HeightField, swan: CameraPath) -> None:
    assert len(swan) == 600 and swan.name == "swan2002"
    _check_swan(hf, swan, np.zeros(2))


@pytest.mark.parametrize("angle", [0.0, 45.0, 100.0])
def test_swan_ridge_orientations(angle: float) -> None:
    field = _field(97, ridge_angle_deg=angle, height=2500.0)
    path = swan2002(field, 300)
    _check_swan(field, path, np.zeros(2))
    # The flight crosses the ridge roughly at right angles, not along it.
    eyes = path.eyes()
    heading = eyes[-1, :2] - eyes[int(0.3 * len(path)), :2]
    a = math.radians(angle)
    along = np.array([math.sin(a), math.cos(a)])
    assert abs(heading @ along) / np.linalg.norm(heading) < math.sin(math.radians(30.0))


def test_swan_off_centre_peak_and_flat_field() -> None:
    n = 129
    xs = np.linspace(-L / 2, L / 2, n)
    x, y = np.meshgrid(xs, xs[::-1])
    px, py = 0.2 * L, -0.15 * L
    h = 2000.0 * np.exp(-(((x - px) / (0.05 * L)) ** 2 + ((y - py) / (0.05 * L)) ** 2))
    field = HeightField(h.astype(np.float32), L / (n - 1), L / (n - 1))
    path = swan2002(field, 400)
    _check_swan(field, path, np.array([px, py]))
    # Ends of the flight stay inside the terrain.
    end = path.eyes()[-1, :2]
    assert np.all(np.abs(end) <= L / 2)
    flat = HeightField(np.zeros((33, 33), np.float32), 100.0, 100.0)
    p = swan2002(flat, 50)
    _assert_valid_axes(p)
    assert np.all(p.eyes()[:, 2] > 0.0)


# --------------------------------------------------------------------------- JSON


def test_json_round_trip_tuple_form(tmp_path, chen: CameraPath, swan: CameraPath) -> None:
    for path in (chen, swan):
        f = tmp_path / f"{path.name}.json"
        path.to_json(f)
        doc = json.loads(f.read_text())
        assert doc["format"] == "lodsprite-path" and doc["version"] == 1
        assert len(doc["frames"]) == len(path)
        back = load_path_json(f)
        assert back.name == path.name and back.fov_y_deg == path.fov_y_deg
        np.testing.assert_allclose(back.eyes(), path.eyes(), atol=1e-12, rtol=0)
        np.testing.assert_allclose(back.axes(), path.axes(), atol=1e-12, rtol=0)
        assert back.to_dict() == path.to_dict()


def test_json_look_at_form(tmp_path) -> None:
    doc = {
        "format": "lodsprite-path", "version": 1, "name": "mine", "fov_y_deg": 60,
        "frames": [
            {"eye": [0, -5000, 3000], "target": [0, 0, 0]},
            {"eye": [5000, 0, 3000], "target": [0, 0, 100], "up": [0, 0.2, 1]},
            look_at([1, 2, 3], [4, 5, 0]).to_dict(),
        ],
    }
    f = tmp_path / "mine.json"
    f.write_text(json.dumps(doc))
    path = load_path_json(f)
    assert path.name == "mine" and path.fov_y_deg == 60.0 and len(path) == 3
    v0 = path.viewpoints[0]
    np.testing.assert_allclose(v0.o, [0, -5000, 3000])
    to_t = -v0.o / np.linalg.norm(v0.o)
    assert v0.forward @ to_t == pytest.approx(1.0, abs=1e-12)
    assert v0.y[2] > 0 and abs(v0.x[2]) < 1e-12
    g = tmp_path / "again.json"
    path.to_json(g)
    again = load_path_json(g)
    np.testing.assert_allclose(again.eyes(), path.eyes(), atol=1e-12, rtol=0)
    np.testing.assert_allclose(again.axes(), path.axes(), atol=1e-12, rtol=0)
    # Name defaults to the file's stem, fov to 45 degrees.
    del doc["name"], doc["fov_y_deg"]
    f.write_text(json.dumps(doc))
    path = load_path_json(f)
    assert path.name == "mine" and path.fov_y_deg == 45.0


_GOOD = {"x": [1, 0, 0], "y": [0, 1, 0], "z": [0, 0, 1], "o": [0, 0, 10]}


def _doc(**over) -> dict:
    d = {"format": "lodsprite-path", "version": 1, "name": "p", "frames": [_GOOD]}
    d.update(over)
    return d


@pytest.mark.parametrize(("text", "match"), [
    ("{not json", "invalid JSON"),
    (json.dumps([1, 2]), "JSON object"),
    (json.dumps(_doc(format="other")), "format"),
    (json.dumps({k: v for k, v in _doc().items() if k != "format"}), "format"),
    (json.dumps(_doc(version=2)), "version"),
    (json.dumps(_doc(version="1")), "version"),
    (json.dumps(_doc(frames=[])), "empty"),
    (json.dumps(_doc(frames={"a": 1})), "list"),
    (json.dumps(_doc(fov_y_deg=200)), "fov_y_deg"),
    (json.dumps(_doc(name=3)), "name"),
    (json.dumps(_doc(frames=[_GOOD, [1, 2, 3]])), "frame 1"),
    (json.dumps(_doc(frames=[{**_GOOD, "o": [0, 0]}])), "3 numbers"),
    (json.dumps(_doc(frames=[{**_GOOD, "o": [0, 0, 1, 2]}])), "3 numbers"),
    (json.dumps(_doc(frames=[{**_GOOD, "o": [0, "a", 1]}])), "finite numbers"),
    (json.dumps(_doc(frames=[{**_GOOD, "o": [0, True, 1]}])), "finite numbers"),
    (json.dumps(_doc(frames=[{**_GOOD, "o": [0, float("nan"), 1]}])), "finite numbers"),
    (json.dumps(_doc(frames=[{**_GOOD, "x": [1, 0.1, 0]}])), "orthonormal"),
    (json.dumps(_doc(frames=[{**_GOOD, "x": [2, 0, 0]}])), "orthonormal"),
    (json.dumps(_doc(frames=[{**_GOOD, "x": [-1, 0, 0]}])), "right-handed"),
    (json.dumps(_doc(frames=[{**_GOOD, "extra": 1}])), "expected keys"),
    (json.dumps(_doc(frames=[{"eye": [1, 2, 3]}])), "expected keys"),
    (json.dumps(_doc(frames=[{"eye": [1, 2, 3], "target": [1, 2, 3]}])), "same point"),
    (json.dumps(_doc(frames=[{"eye": [0, 0, 9], "target": [0, 0, 0]}])), "parallel"),
    (json.dumps(_doc(frames=[{"eye": [0, 1, 9], "target": [0, 0, 0], "up": [0, 0, 0]}])),
     "zero"),
])
def test_json_malformed(tmp_path, text: str, match: str) -> None:
    f = tmp_path / "bad.json"
    f.write_text(text)
    with pytest.raises(PathError, match=match) as info:
        load_path_json(f)
    assert "\n" not in str(info.value)


def test_json_missing_file(tmp_path) -> None:
    with pytest.raises(PathError, match="not found"):
        load_path_json(tmp_path / "nope.json")


# --------------------------------------------------------------------------- resampling, lookup


def test_resampled(chen: CameraPath, swan: CameraPath, hf: HeightField) -> None:
    for path in (chen, swan):
        for n in (2, 37, 301):
            r = path.resampled(n)
            assert len(r) == n and r.name == path.name and r.fov_y_deg == path.fov_y_deg
            for k in (0, -1):
                for attr in ("x", "y", "z", "o"):
                    np.testing.assert_array_equal(getattr(r.viewpoints[k], attr),
                                                  getattr(path.viewpoints[k], attr))
            _assert_valid_axes(r)
            assert _dist_to_polyline(r.eyes(), path.eyes()).max() < 1e-6 * L
    # Resampling by frame index keeps the timing: it matches chen1999 built with 920 frames.
    r = chen.resampled(920)
    direct = chen1999(hf, 920)
    np.testing.assert_allclose(r.eyes(), direct.eyes(), atol=1e-4 * L)
    np.testing.assert_allclose(r.axes(), direct.axes(), atol=1e-4)
    with pytest.raises(PathError):
        chen.resampled(1)
    single = CameraPath("one", (chen.viewpoints[5],))
    assert len(single.resampled(4)) == 4


def test_get_path(tmp_path, hf: HeightField, chen: CameraPath) -> None:
    assert len(get_path("chen1999", hf)) == 460
    assert len(get_path("Swan2002", hf, frames=None)) == 600
    assert len(get_path("chen1999", hf, frames=115)) == 115
    assert len(get_path("swan2002", hf, frames=60)) == 60
    f = tmp_path / "p.json"
    chen.to_json(f)
    assert len(get_path(str(f), hf)) == 460
    assert len(get_path(f, hf, frames=50)) == 50
    with pytest.raises(PathError, match="unknown path 'orbit': use chen1999, swan2002"):
        get_path("orbit", hf)
    with pytest.raises(PathError, match="not found"):
        get_path(str(tmp_path / "missing.json"), hf)
    with pytest.raises(PathError):
        get_path("chen1999", hf, frames=1)


def test_camera_path_validation(chen: CameraPath) -> None:
    with pytest.raises(PathError):
        CameraPath("empty", ())
    with pytest.raises(PathError):
        CameraPath("fov", chen.viewpoints[:2], fov_y_deg=180.0)
    p = CameraPath("list", list(chen.viewpoints[:3]))
    assert isinstance(p.viewpoints, tuple) and p.eyes().shape == (3, 3)
