import msgpack
import numpy as np
import pytest

from lodsprite.camera import Projection, look_at
from lodsprite.distributed.protocol import (
    PROTOCOL_VERSION,
    Keyframe,
    ProtocolError,
    decode,
    decode_keyframe,
    encode,
    encode_keyframe,
    shown_from_wire,
)


def keyframe(seq=7, h=24, w=32, zbuffer="full") -> Keyframe:
    rng = np.random.default_rng(seq)
    return Keyframe(seq, 123.25, look_at((10.0, -500.0, 300.0), (0.0, 0.0, 0.0)),
                    Projection(45.0, w / h, 2.5, 9000.0),
                    rng.integers(0, 256, (h, w, 3), dtype=np.uint8),
                    rng.random((h, w), dtype=np.float32), zbuffer)


@pytest.mark.parametrize("zbuffer", ["full", "coarse"])
@pytest.mark.parametrize("codec", ["raw", "zlib"])
def test_keyframe_round_trip_keeps_every_field(codec, zbuffer):
    kf = keyframe(zbuffer=zbuffer)
    back = decode_keyframe(encode_keyframe(kf, codec))
    assert back.seq == kf.seq and back.t0 == kf.t0 and back.zbuffer == zbuffer
    for k in "xyzo":
        np.testing.assert_array_equal(getattr(back.viewpoint, k), getattr(kf.viewpoint, k))
    assert back.projection == kf.projection
    np.testing.assert_array_equal(back.color, kf.color)
    np.testing.assert_array_equal(back.depth, kf.depth)
    header, buffers = decode(encode_keyframe(kf, codec))
    np.testing.assert_allclose(np.reshape(header["view"], (4, 4)), kf.viewpoint.view_matrix())
    np.testing.assert_allclose(np.reshape(header["proj"], (4, 4)), kf.projection.matrix())
    assert len(buffers) == 2


def test_images_travel_raw_not_pickled_rows_bottom_up():
    kf = keyframe()
    frames = encode_keyframe(kf, "raw")
    assert bytes(frames[1]) == kf.color[::-1].tobytes()
    assert bytes(frames[2]) == kf.depth[::-1].tobytes()
    assert b"pickle" not in frames[0]


def test_gl_rows_cross_the_wire_without_a_copy():
    # A flipped view of bottom-up rows (a GL read-back) is sent as its own buffer, and a
    # decoded keyframe's images are views of the received frames.
    gl_color = np.arange(24 * 32 * 3, dtype=np.uint8).reshape(24, 32, 3)
    gl_depth = np.linspace(0, 1, 24 * 32, dtype=np.float32).reshape(24, 32)
    kf = keyframe()
    kf = Keyframe(kf.seq, kf.t0, kf.viewpoint, kf.projection, gl_color[::-1], gl_depth[::-1])
    frames = encode_keyframe(kf, "raw")
    assert np.shares_memory(frames[1], gl_color) and np.shares_memory(frames[2], gl_depth)
    received = [bytes(frames[0]), bytearray(frames[1]), bytearray(frames[2])]
    back = decode_keyframe(received)
    np.testing.assert_array_equal(back.color, gl_color[::-1])
    assert back.color[::-1].flags.c_contiguous  # what a texture upload takes as it is
    received[1][0] = 99  # the first byte: bottom row, first pixel, red
    assert back.color[-1, 0, 0] == 99


def corrupt(frames, **changes):
    header = msgpack.unpackb(frames[0], raw=False)
    for k, v in changes.items():
        if v is None:
            header.pop(k, None)
        else:
            header[k] = v
    return [msgpack.packb(header, use_bin_type=True), *frames[1:]]


@pytest.mark.parametrize("frames", [
    [],
    [b"\xc1 not msgpack"],
    [msgpack.packb([1, 2, 3])],
    encode({"kind": "nonsense", "seq": 1}),
    encode({"kind": "ack", "seq": -1}),
    encode({"kind": "ack", "seq": True}),
    corrupt(encode({"kind": "ack", "seq": 1}), v=PROTOCOL_VERSION + 1),
    corrupt(encode({"kind": "ack", "seq": 1}), v=None),
])
def test_malformed_and_wrong_version_messages_are_rejected(frames):
    with pytest.raises(ProtocolError):
        decode(frames)


def test_malformed_keyframes_are_rejected():
    good = [bytes(f) for f in encode_keyframe(keyframe())]
    bad = [
        good[:2],                                    # depth buffer missing
        [good[0], good[1][:-1], good[2]],            # truncated colour
        [good[0], good[1], good[2] + b"\x00"],       # oversized depth
        corrupt(good, viewpoint={"x": [1, 0, 0]}),    # viewpoint incomplete
        corrupt(good, viewpoint={"x": [1, 0, 0], "y": [1, 0, 0], "z": [0, 0, 1],
                                 "o": [0, 0, 0]}),   # axes not orthonormal
        corrupt(good, near=None),
        corrupt(good, near=5.0, far=1.0),
        corrupt(good, t0="yesterday"),
        corrupt(good, zbuffer="half"),
        corrupt(good, zbuffer=None),
        corrupt(good, color={"shape": [24, 32, 3], "dtype": "float64", "codec": "raw"}),
        corrupt(good, color={"shape": [24, 32], "dtype": "uint8", "codec": "raw"}),
        corrupt(good, depth={"shape": [24, 32], "dtype": "float32", "codec": "lz4"}),
        corrupt(good, depth={"shape": [24, 31], "dtype": "float32", "codec": "raw"}),
        [corrupt(good, color={"shape": [24, 32, 3], "dtype": "uint8", "codec": "zlib"})[0],
         b"not zlib", good[2]],
    ]
    for frames in bad:
        with pytest.raises(ProtocolError):
            decode_keyframe(frames)


def test_the_shown_keyframe_is_optional_and_checked():
    assert shown_from_wire(None) is None
    eye, slot = shown_from_wire({"eye": [1.0, 2, -3.5], "slot": 1})
    assert eye.tolist() == [1.0, 2.0, -3.5] and slot == 1
    for bad in ([1.0, 2.0, 3.0], {"eye": [1.0, 2.0], "slot": 0},
                {"eye": [1.0, 2.0, float("nan")], "slot": 0}, {"eye": "here", "slot": 0},
                {"eye": [1.0, 2.0, 3.0]}, {"eye": [1.0, 2.0, 3.0], "slot": -1},
                {"eye": [1.0, 2.0, 3.0], "slot": True}, {"eye": [1.0, 2.0, 3.0], "slot": 0.5}):
        with pytest.raises(ProtocolError):
            shown_from_wire(bad)
