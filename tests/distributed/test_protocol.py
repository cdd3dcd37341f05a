import msgpack
import numpy as np
import pytest

from lodsprite.camera import Projection, look_at
from lodsprite.distributed.protocol import (
    PROTOCOL_VERSION,
    Keyframe,
    ProtocolError,
    check_load_args,
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


def test_a_keyframe_says_what_it_lacks_and_a_hostile_deficit_is_refused():
    from dataclasses import replace

    kf = replace(keyframe(), deficit_px=2.75)
    assert decode_keyframe(encode_keyframe(kf)).deficit_px == 2.75
    assert decode_keyframe(encode_keyframe(keyframe())).deficit_px == 0.0
    header, buffers = decode(encode_keyframe(kf))
    for bad in (-1.0, 1e9, "x"):
        frames = encode({**header, "deficit_px": bad}, *buffers)
        with pytest.raises(ProtocolError):
            decode_keyframe(frames)


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


# ----------------------------------------------------- bounded decoding (issue 12, item 2)

def _zlib_keyframe(shape, stream: bytes) -> list:
    good = [bytes(f) for f in encode_keyframe(keyframe())]
    return [corrupt(good, color={"shape": list(shape), "dtype": "uint8", "codec": "zlib"})[0],
            stream, good[2]]


def _peak_bytes(f) -> int:
    import tracemalloc

    tracemalloc.start()
    try:
        f()
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    return peak


def test_a_zlib_bomb_is_refused_without_inflating_it():
    """Regression: zlib.decompress inflated the whole stream before checking its size."""
    import zlib

    bomb = zlib.compress(b"\x00" * (200 * 2**20), 9)  # 200 MiB of zeros in about 200 KB
    frames = _zlib_keyframe((24, 32, 3), bomb)

    def run():
        with pytest.raises(ProtocolError, match="beyond"):
            decode_keyframe(frames)
    assert _peak_bytes(run) < 8 * 2**20


def test_a_declared_shape_allocates_nothing_by_itself():
    """Regression: the declared size was passed to zlib as its buffer size, so a small
    message made the receiver allocate what the header declared (up to 16384² x 3)."""
    import zlib

    frames = _zlib_keyframe((4096, 4096, 3), zlib.compress(b"\x01" * 100))

    def run():
        with pytest.raises(ProtocolError):
            decode_keyframe(frames)
    assert _peak_bytes(run) < 8 * 2**20
    with pytest.raises(ProtocolError):  # over the cap: refused from the header alone
        decode_keyframe(_zlib_keyframe((8192, 8192, 3), b""))


def test_zlib_images_must_inflate_to_exactly_their_size_and_end_there():
    import zlib

    kf = keyframe()
    size = kf.color.nbytes
    raw = np.ascontiguousarray(kf.color[::-1]).tobytes()
    good = zlib.compress(raw)
    assert bytes(decode_keyframe(_zlib_keyframe((24, 32, 3), good)).color[::-1]) == raw
    for stream in (good[:-5], good + b"trailing", zlib.compress(raw[:-1]),
                   zlib.compress(raw + b"x"), b""):
        with pytest.raises(ProtocolError):
            decode_keyframe(_zlib_keyframe((24, 32, 3), stream))
    assert size == 24 * 32 * 3


@pytest.mark.parametrize("change", [
    {"color": {"shape": [24, 32, 3.0], "dtype": "uint8", "codec": "raw"}},  # killed the client
    {"color": {"shape": [24.0, 32, 3], "dtype": "uint8", "codec": "raw"}},
    {"color": {"shape": [24, 32, 3], "dtype": "uint8", "codec": "raw", "x": 1}},
    {"color": {"shape": [24, 32, 3, 1], "dtype": "uint8", "codec": "raw"}},
    {"color": {"shape": [0, 32, 3], "dtype": "uint8", "codec": "raw"}},
    {"color": "24x32"},
    {"seq": 2**64 - 1},
    {"t0": float("nan")},
    {"fov": 180.0},
    {"view": [0.0] * 15},
    {"viewpoint": {"x": [1, 0, 0], "y": [0, 1, 0], "z": [0, 0, 1], "o": [0, 0, "1"]}},
    {"extra": True},
    {"v": 2},
])
def test_keyframe_headers_are_typed(change):
    good = [bytes(f) for f in encode_keyframe(keyframe())]
    with pytest.raises(ProtocolError):
        decode_keyframe(corrupt(good, **change))


def test_messages_carry_exactly_their_buffers():
    with pytest.raises(ProtocolError, match="buffers"):
        decode(encode({"kind": "ack", "seq": 1}, b"unexpected"))
    good = [bytes(f) for f in encode_keyframe(keyframe())]
    with pytest.raises(ProtocolError, match="buffers"):
        decode_keyframe([*good, b""])


def test_control_arguments_are_typed_per_op():
    from lodsprite.distributed.protocol import LoadArgs, NoArgs, decode_message

    msg, _ = decode_message(encode({"kind": "control", "seq": 1, "op": "load",
                                    "args": {"terrain": "fractal:64:1", "grid": 64}}))
    assert isinstance(msg.args, LoadArgs) and msg.args.grid == 64 and msg.args.lod == 16
    msg, _ = decode_message(encode({"kind": "control", "seq": 1, "op": "ping"}))
    assert isinstance(msg.args, NoArgs)
    for bad in ({"op": "ping", "args": {"x": 1}}, {"op": "launch"},
                {"op": "load", "args": {"grid": 64.0}}, {"op": "ping", "client": "XYZ"}):
        with pytest.raises(ProtocolError):
            decode(encode({"kind": "control", "seq": 1, **bad}))


def test_the_protocol_knows_the_renderers_visibility_rules_and_paces():
    from lodsprite.distributed.pacing import PACES
    from lodsprite.distributed.protocol import PACE_NAMES, VISIBILITY
    from lodsprite.gl.sprite import VISIBILITY_MODES

    assert set(VISIBILITY) == set(VISIBILITY_MODES) and set(PACE_NAMES) == set(PACES)


def test_every_link_socket_caps_its_message_size():
    import zmq

    from lodsprite.distributed.link import ServerLink
    from lodsprite.distributed.protocol import MAX_KEYFRAME_FRAME_BYTES

    ctx = zmq.Context()
    link = ServerLink(ctx, "127.0.0.1:59991")
    try:
        assert link.keyframes.getsockopt(zmq.MAXMSGSIZE) == MAX_KEYFRAME_FRAME_BYTES
        assert link.viewpoint.getsockopt(zmq.MAXMSGSIZE) > 0
        assert link.keyframes.getsockopt(zmq.IDENTITY) == link.client_id.encode()
        assert len(link.client_id) == 16
    finally:
        link.close()
        ctx.destroy(linger=0)


def test_a_load_asks_for_a_keyframe_scale_the_sprite_drawer_knows_within_the_image_cap():
    import msgspec

    from lodsprite.distributed.messages import KEY_SCALES, LoadArgs
    from lodsprite.distributed.render import key_size
    from lodsprite.gl.sprite import KEY_SCALES as DRAWER_SCALES

    assert KEY_SCALES == DRAWER_SCALES
    args = msgspec.convert({"size": [640, 480], "key_scale": 1.5}, LoadArgs)
    assert key_size(args) == (960, 720)
    for bad in ({"size": [640, 480], "key_scale": 1.25},  # not one of the scales
                {"size": [3000, 480], "key_scale": 1.5},  # 4500 px: over the image cap
                {"size": [640, 480], "key_scale": 3}):
        with pytest.raises(ProtocolError):
            check_load_args(bad)
