"""ZeroMQ CURVE keys for the LOD server and its clients.

``lodsprite keys --out DIR`` writes ``server.key`` / ``server.key_secret`` and
``client.key`` / ``client.key_secret`` (ZeroMQ certificate files).  A server started with
``--keys DIR`` encrypts all three connections and accepts only clients whose public key
file is in DIR; a client started with ``--keys DIR`` uses ``client.key_secret`` and
``server.key``.  Copy DIR's ``server.key`` and a client's pair to the client machine.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import zmq
import zmq.auth

from lodsprite.errors import InputError


def make_keys(out_dir: Path) -> list[Path]:
    """Create the server and client key pairs in ``out_dir``; returns the files written."""
    if not zmq.has("curve"):
        raise InputError("this ZeroMQ build has no CURVE support")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files = []
    for name in ("server", "client"):
        files += [Path(p) for p in zmq.auth.create_certificates(str(out_dir), name)]
    return files


def _load(path: Path, secret: bool) -> tuple[bytes, bytes | None]:
    if not path.is_file():
        raise InputError(f"key file not found: {path}")
    try:
        public, sec = zmq.auth.load_certificate(str(path))
    except (ValueError, OSError) as exc:
        raise InputError(f"unreadable key file {path}: {exc}") from exc
    if secret and sec is None:
        raise InputError(f"{path} holds no secret key")
    return public, sec


@dataclass(frozen=True)
class ServerKeys:
    public: bytes
    secret: bytes
    clients_dir: Path

    @classmethod
    def load(cls, keys_dir: Path) -> ServerKeys:
        public, secret = _load(Path(keys_dir) / "server.key_secret", True)
        return cls(public, secret, Path(keys_dir))

    def apply(self, sock: zmq.Socket) -> None:
        sock.curve_secretkey = self.secret
        sock.curve_publickey = self.public
        sock.curve_server = True


@dataclass(frozen=True)
class ClientKeys:
    public: bytes
    secret: bytes
    server_public: bytes

    @classmethod
    def load(cls, keys_dir: Path) -> ClientKeys:
        return cls.from_files(Path(keys_dir) / "client.key_secret",
                              Path(keys_dir) / "server.key")

    @classmethod
    def from_files(cls, secret_file: Path, server_file: Path) -> ClientKeys:
        """The pair in ``secret_file`` (a ``.key_secret``) and the server's public key in
        ``server_file``; raises :class:`InputError` naming a missing or unreadable file."""
        public, secret = _load(Path(secret_file), True)
        server_public, _ = _load(Path(server_file), False)
        return cls(public, secret, server_public)

    def apply(self, sock: zmq.Socket) -> None:
        sock.curve_secretkey = self.secret
        sock.curve_publickey = self.public
        sock.curve_serverkey = self.server_public
