"""Two hosts on one machine: network namespaces joined by a veth pair, optionally
rate-limited with a token-bucket filter (the paper's 10BASE-T link, or 100BASE-T).

Both ends live in namespaces this run creates (``lsp-c-PID`` for the client,
``lsp-s-PID`` for the server), addressed ``10.213.0.1`` and ``10.213.0.2`` inside them
only; everything is removed on exit, also on failure.  Needs root and iproute2
(:func:`available` says whether this process may).
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

CLIENT_IP, SERVER_IP = "10.213.0.1", "10.213.0.2"
RATES = {"10mbit": "10mbit", "100mbit": "100mbit", "unlimited": None}


def available() -> str | None:
    """None if namespaces can be made here, else the reason they cannot."""
    if os.geteuid() != 0:
        return "needs root to create network namespaces"
    if shutil.which("ip") is None or shutil.which("tc") is None:
        return "needs iproute2 (ip, tc)"
    probe = f"lsp-probe-{os.getpid()}"
    made = subprocess.run(["ip", "netns", "add", probe], capture_output=True)
    if made.returncode != 0:
        return "ip netns add failed: " + made.stderr.decode(errors="replace").strip()
    subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return None


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True)


@dataclass(frozen=True)
class TwoHosts:
    """The namespaces and the command prefix that runs a program in each."""

    client_ns: str
    server_ns: str

    def client(self, cmd: list[str]) -> list[str]:
        return ["ip", "netns", "exec", self.client_ns, *cmd]

    def server(self, cmd: list[str]) -> list[str]:
        return ["ip", "netns", "exec", self.server_ns, *cmd]


@contextmanager
def two_hosts(rate: str | None) -> Iterator[TwoHosts]:
    """Client and server namespaces joined by a veth pair limited to ``rate`` (tc syntax,
    e.g. ``10mbit``; None for no limit)."""
    pid = os.getpid()
    hosts = TwoHosts(f"lsp-c-{pid}", f"lsp-s-{pid}")
    veth_c, veth_s = f"lspc{pid}"[:15], f"lsps{pid}"[:15]
    try:
        for ns in (hosts.client_ns, hosts.server_ns):
            _ip("netns", "add", ns)
            _ip("-n", ns, "link", "set", "lo", "up")
        _ip("link", "add", veth_c, "netns", hosts.client_ns, "type", "veth", "peer", "name",
            veth_s, "netns", hosts.server_ns)
        for ns, dev, ip in ((hosts.client_ns, veth_c, CLIENT_IP),
                            (hosts.server_ns, veth_s, SERVER_IP)):
            _ip("-n", ns, "addr", "add", f"{ip}/30", "dev", dev)
            _ip("-n", ns, "link", "set", dev, "up")
            if rate:
                subprocess.run(["ip", "netns", "exec", ns, "tc", "qdisc", "add", "dev", dev,
                                "root", "tbf", "rate", rate, "burst", "32kbit", "latency",
                                "400ms"], check=True, capture_output=True)
        yield hosts
    finally:
        for ns in (hosts.client_ns, hosts.server_ns):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)
