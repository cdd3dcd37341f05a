"""The ``path`` op a web page sends after its ``load`` (the server computes the path's
viewpoints, so the page plays the Python side's path) and the scene's ``relief`` (the
page's error estimate): what they answer, and what they refuse."""


import msgspec
import numpy as np
import pytest

from lodsprite.distributed.protocol import (
    LoadArgs,
    PathArgs,
    ProtocolError,
    decode_message,
    encode,
)
from lodsprite.distributed.web.scene import path_data, relief
from lodsprite.distributed.web.sessions import Session
from lodsprite.distributed.web.wire import pack_message, unpack

LOAD = LoadArgs(terrain="fractal:64:4", grid=64, lod=8, size=(64, 64))


def control(op: str, args: dict) -> list:
    return encode({"kind": "control", "seq": 3, "op": op, "args": args})


def test_the_path_s_viewpoints_are_those_of_get_path():
    from lodsprite.paths import get_path
    from lodsprite.scene import load_scene

    data = path_data(LOAD, PathArgs("chen1999", 7))
    want = get_path("chen1999", load_scene("fractal:64:4", "terrain", 64, 1.0).hf, 7)
    rows = np.array(data["viewpoints"])
    assert rows.shape == (7, 12) and data["fov"] == want.fov_y_deg
    for row, vp in zip(rows, want.viewpoints, strict=True):
        np.testing.assert_array_equal(row, np.concatenate([vp.x, vp.y, vp.z, vp.o]))
    assert msgspec.msgpack.decode(msgspec.msgpack.encode(data)) == data  # crosses the wire


@pytest.mark.parametrize("args", [
    {"spec": "/etc/passwd"}, {"spec": "path.json"}, {"spec": "../chen1999"},
    {"spec": "flyover:1:2:3:4"}, {"spec": "chen1999", "frames": 1},
    {"spec": "chen1999", "frames": 10**6}, {"spec": "chen1999", "file": "x"},
])
def test_path_refuses_files_and_unknown_specs(args):
    with pytest.raises(ProtocolError):
        decode_message(control("path", args))


def test_path_takes_the_built_in_specs():
    for spec in ("chen1999", "swan2002", "flyover", "flyover:120:3000", "patrol:80:2000:3",
                 "bank:60"):
        msg, _ = decode_message(control("path", {"spec": spec, "frames": 20}))
        assert msg.args == PathArgs(spec, 20)


class Hub:
    def __init__(self):
        self.paths = []

    def path(self, session, args, seq):
        self.paths.append((args, seq))

    def schedule(self):
        pass


def test_a_session_hands_path_to_the_hub_and_refuses_it_before_a_load():
    hub = Hub()
    s = Session(hub)
    s.handle(pack_message({"kind": "control", "seq": 5, "op": "path",
                           "args": {"spec": "chen1999", "frames": 9}}))
    assert hub.paths == [(PathArgs("chen1999", 9), 5)] and s.counts["internal"] == 0
    from lodsprite.distributed.web.hub import Hub as RealHub

    RealHub(None, None).path(s, PathArgs(), 6)  # no load yet: refused, not raised
    reply = msgspec.msgpack.decode(unpack(s._replies[-1])[0])
    assert reply["seq"] == 6 and reply["ok"] is False and "load" in reply["error"]


def test_relief_is_the_rms_of_the_centres_off_the_coarse_surface():
    x, y = np.meshgrid(np.arange(9.0), np.arange(9.0))
    plane = 3.0 * x - 2.0 * y + 7.0
    assert relief(plane, 4) == pytest.approx(0.0, abs=1e-12)  # a plane: the coarse level
    bumps = plane.copy()
    bumps[2, 2] += 5.0  # the centre of one of the four squares
    assert relief(bumps, 4) == pytest.approx(np.sqrt(25.0 / 4))
    assert relief(bumps, 1) == 0.0
