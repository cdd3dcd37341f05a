"""The web server's edge: address, token, Origin, rate and TLS rules.

* **Loopback by default.** ``--web PORT`` binds 127.0.0.1; another host needs
  ``--allow-remote`` (as the ZeroMQ server's ``--bind``).
* **Token.** ``GET /`` and ``GET /ws`` carry ``?token=T``; a missing or wrong token is
  401 on the page and 403 on the WebSocket, compared in constant time
  (:func:`secrets.compare_digest`).  Without ``--token`` one is generated
  (:func:`secrets.token_urlsafe`) and the page's full URL printed at start.  Off
  loopback (``--allow-remote`` or a non-loopback ``--web`` host) a given token must have
  at least :data:`MIN_REMOTE_TOKEN` characters: the token is all that stands between
  the network and the renderers.
* **Origin.** A browser sends ``Origin`` with every WebSocket handshake; it must be the
  server's own as the browser reached it: ``http(s)://`` + the request's ``Host``, so
  another site's page (even one that knows the token) cannot open the WebSocket.  A
  request without ``Origin`` is not from a browser page (scripts, benchmarks); it is let
  in on the token alone.
* **Host** (DNS rebinding: a page of another site whose name the attacker re-points at
  this machine reaches the server under the attacker's name).  Every request, page,
  static file and WebSocket alike, must name this server in ``Host``: a loopback name,
  the bound host, an IP address (a rebinding page always sends its own name, never an
  address), or a ``--public-host`` name (the names users reach it by: a DNS name, a
  reverse proxy's).  Others get 421 (Misdirected Request).  Binding all interfaces
  (``0.0.0.0``) accepts no more names than that: reached by a name, pass it as
  ``--public-host``.
* **Rate.** :class:`RateLimit`: a token bucket per session (``--rate`` messages/s, a
  second's worth of burst); messages over it are dropped and counted.
"""

from __future__ import annotations

import secrets
import ssl
import time
from pathlib import Path

from lodsprite.distributed.messages import LOOPBACK_HOSTS
from lodsprite.errors import InputError

__all__ = ["DEFAULT_WEB_HOST", "LOOPBACK_NAMES", "MIN_REMOTE_TOKEN", "RateLimit", "check_host",
           "check_origin", "make_token", "parse_web_address", "tls_context", "token_ok"]

DEFAULT_WEB_HOST = "127.0.0.1"
LOOPBACK_NAMES = LOOPBACK_HOSTS
MIN_REMOTE_TOKEN = 16
"""Fewest characters of a ``--token`` off loopback (a generated one has 43)."""


def parse_web_address(address: str, allow_remote: bool = False) -> tuple[str, int]:
    """``(host, port)`` of ``[HOST:]PORT`` (port 0: any free port); raises
    :class:`InputError` for a malformed address or a non-loopback host without
    ``allow_remote``."""
    host, _, port = str(address).rpartition(":")
    host = host.strip("[]") or DEFAULT_WEB_HOST
    if not port.isdigit() or not 0 <= int(port) <= 65535:
        raise InputError(f"--web takes [HOST:]PORT, got '{address}'")
    if host not in LOOPBACK_NAMES and not allow_remote:
        raise InputError(f"serving the web page on {host} exposes it beyond this machine: "
                         "pass --allow-remote (and use TLS: --cert/--key or a reverse proxy)")
    return host, int(port)


def make_token(token: str | None, remote: bool = False) -> str:
    """``token``, or a new random one (URL-safe, 32 bytes of entropy); ``remote``: the
    page is served off loopback, where a given token needs :data:`MIN_REMOTE_TOKEN`
    characters.  Raises :class:`InputError` for a token it refuses."""
    if token is None:
        return secrets.token_urlsafe(32)
    if not token or len(token) > 256 or not token.isprintable() or " " in token:
        raise InputError("--token must be 1..256 printable characters without spaces")
    if remote and len(token) < MIN_REMOTE_TOKEN:
        raise InputError(f"--token must have at least {MIN_REMOTE_TOKEN} characters when "
                         f"the page is served beyond loopback (it has {len(token)}; omit "
                         "--token for a random one)")
    return token


def token_ok(given: str | None, token: str) -> bool:
    """Whether the request's ``given`` token is ``token`` (constant-time)."""
    return given is not None and secrets.compare_digest(given.encode(), token.encode())


def check_host(host_header: str | None, bound: str, public: tuple[str, ...] = ()) -> bool:
    """Whether a request's ``Host`` header (``name[:port]``, ``[v6][:port]``) names this
    server: a loopback name, the bound host, an IP address, or one of the ``public``
    names (``--public-host``), compared without case.  A wildcard bind adds no names."""
    if not host_header:
        return False
    name = host_header if host_header.endswith("]") else host_header.rsplit(":", 1)[0]
    if host_header.count(":") > 1 and not host_header.startswith("["):
        name = host_header  # a bare IPv6 address, no port
    name = name.strip("[]").rstrip(".").lower()
    if not name:
        return False
    return (name in LOOPBACK_NAMES or name == bound.strip("[]").lower() or _is_address(name)
            or name in {p.rstrip(".").lower() for p in public})


def _is_address(name: str) -> bool:
    """Whether ``name`` is an IPv4 or IPv6 address (never a DNS-rebinding page's Host)."""
    import ipaddress

    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def check_origin(origin: str | None, host_header: str | None) -> bool:
    """Whether a WebSocket handshake's ``Origin`` is the server's own
    (``http(s)://`` + ``Host``); no ``Origin`` (not a browser page) passes."""
    if origin is None:
        return True
    if not host_header:
        return False
    return origin in (f"http://{host_header}", f"https://{host_header}")


def tls_context(cert: Path | None, key: Path | None) -> ssl.SSLContext | None:
    """A server TLS context from PEM ``cert`` and ``key`` files (None: plain HTTP);
    raises :class:`InputError` for a missing or unreadable pair."""
    if cert is None and key is None:
        return None
    if cert is None or key is None:
        raise InputError("TLS needs both --cert and --key")
    ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    try:
        ctx.load_cert_chain(str(cert), str(key))
    except (OSError, ssl.SSLError) as exc:
        raise InputError(f"cannot load the TLS certificate {cert} and key {key}: {exc}") from None
    return ctx


class RateLimit:
    """A token bucket: ``rate`` messages a second, bursts of up to ``rate`` (one
    second's worth); :meth:`allow` says whether one more message may pass."""

    def __init__(self, rate: float, clock=time.monotonic) -> None:
        if not rate > 0:
            raise InputError(f"the rate cap must be positive, got {rate}")
        self.rate = float(rate)
        self.clock = clock
        self._tokens = self.rate
        self._last = clock()

    def allow(self) -> bool:
        now = self.clock()
        self._tokens = min(self.rate, self._tokens + (now - self._last) * self.rate)
        self._last = now
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            return True
        return False
