"""The web server's edge rules without renderers: `serve --web` refusals (one line, exit
2), Host and Origin rules, TLS with --cert/--key, and --public-host behind a proxy."""

import asyncio
import shutil
import ssl
import subprocess

import aiohttp
import pytest

from conftest import run_cli
from lodsprite.distributed.web.security import check_host, check_origin
from lodsprite.distributed.web.server import WebConfig, WebServer
from lodsprite.distributed.web.sessions import Caps

TOKEN = "t0ken"


class NoPool:
    def workers(self):
        return []

    def poll(self):
        return []

    def fileno(self):
        return self._r

    def __init__(self):
        import os

        self._r, self._w = os.pipe()


@pytest.mark.parametrize(("args", "fragment"), [
    (["--web", "0.0.0.0:8080"], "--allow-remote"),
    (["--web", "nope"], "[HOST:]PORT"),
    (["--web", "8080", "--cert", "x.pem"], "both --cert and --key"),
    (["--web", "8080", "--cert", "x.pem", "--key", "y.pem"], "cannot load the TLS"),
    (["--web", "8080", "--token", "a b"], "--token"),
    # was: a one-character token accepted for a page served beyond this machine
    (["--web", "0.0.0.0:0", "--allow-remote", "--token", "x"], "at least 16 characters"),
    (["--web", "0", "--allow-remote", "--token", "x" * 15], "at least 16 characters"),
    (["--web", "8080", "--data", "/no/such/folder"], "data folder not found"),
])
def test_bad_web_options_are_one_line_and_exit_2(args, fragment):
    proc = run_cli("serve", *args)
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and fragment in lines[0], proc.stderr


def test_host_and_origin_rules():
    assert check_host("127.0.0.1:8080", "127.0.0.1") and check_host("localhost:1", "127.0.0.1")
    assert check_host("[::1]:8080", "127.0.0.1")
    assert not check_host("evil.example:8080", "127.0.0.1") and not check_host(None, "x")
    assert check_host("lod.example", "127.0.0.1", ("lod.example",))
    assert not check_host("anything:1", "0.0.0.0")  # was: any name on a wildcard bind
    assert check_host("192.168.1.7:8080", "0.0.0.0") and check_host("[fe80::1]:80", "::")
    assert check_host("LOD.example.:443", "0.0.0.0", ("lod.example",))
    assert not check_host(":80", "0.0.0.0") and not check_host("lod.example.evil", "0.0.0.0",
                                                                ("lod.example",))
    assert check_origin(None, "127.0.0.1:8080")  # not a browser page: the token decides
    assert check_origin("https://127.0.0.1:8080", "127.0.0.1:8080")
    assert not check_origin("http://127.0.0.1:8081", "127.0.0.1:8080")
    assert not check_origin("null", "127.0.0.1:8080")


async def statuses(config: WebConfig, requests: list, ssl_ctx=None) -> list[int]:
    server = WebServer(config, pool=NoPool())
    await server.start()
    scheme = "https" if config.tls else "http"
    try:
        async with aiohttp.ClientSession() as http:
            out = []
            for path, headers in requests:
                async with http.get(f"{scheme}://127.0.0.1:{server.port}{path}",
                                    headers=headers, ssl=ssl_ctx) as r:
                    out.append(r.status)
            return out
    finally:
        await server.stop()


@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command")
def test_tls_with_cert_and_key(tmp_path):
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1",
                    "-subj", "/CN=127.0.0.1", "-keyout", str(key), "-out", str(cert)],
                   check=True, capture_output=True, timeout=60)
    tls = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    tls.load_cert_chain(str(cert), str(key))
    client = ssl.create_default_context(cafile=str(cert))
    client.check_hostname = False
    got = asyncio.run(statuses(WebConfig(token=TOKEN, tls=tls, caps=Caps()),
                               [(f"/?token={TOKEN}", {}), ("/", {})], client))
    assert got == [200, 401]


def test_a_public_host_is_accepted_as_host_behind_a_proxy():
    config = WebConfig(token=TOKEN, public_hosts=("lod.example",))
    got = asyncio.run(statuses(config, [(f"/?token={TOKEN}", {"Host": "lod.example"}),
                                        (f"/?token={TOKEN}", {"Host": "other.example"})]))
    assert got == [200, 421]


def test_a_foreign_host_gets_421_on_every_route_even_bound_to_all_interfaces():
    """DNS rebinding: a page of rebind.example re-pointed at this machine sends its own
    name as Host.  Regression: bound to 0.0.0.0 the server accepted any Host."""
    config = WebConfig(host="0.0.0.0", token=TOKEN)
    evil, mine = {"Host": "rebind.example:8080"}, {"Host": "127.0.0.1"}
    ws = {"Connection": "Upgrade", "Upgrade": "websocket", "Sec-WebSocket-Version": "13",
          "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ=="}
    got = asyncio.run(statuses(config, [
        (f"/?token={TOKEN}", evil), ("/static/index.html", evil),
        (f"/ws?token={TOKEN}", {**evil, **ws}), (f"/?token={TOKEN}", mine),
        ("/static/index.html", mine), (f"/?token={TOKEN}", {"Host": "10.0.0.5:8080"})]))
    assert got == [421, 421, 421, 200, 200, 200]


def test_the_page_is_served_with_its_security_headers():
    async def go():
        server = WebServer(WebConfig(token=TOKEN), pool=NoPool())
        await server.start()
        try:
            async with aiohttp.ClientSession() as http, http.get(
                    f"http://127.0.0.1:{server.port}/?token={TOKEN}") as r:
                return r.headers
        finally:
            await server.stop()

    headers = asyncio.run(go())
    assert "script-src 'self'" in headers["Content-Security-Policy"]
    assert "frame-ancestors 'none'" in headers["Content-Security-Policy"]
    assert headers["Referrer-Policy"] == "no-referrer" and headers["Cache-Control"] == "no-store"


def test_static_files_stay_inside_the_static_folder():
    got = asyncio.run(statuses(WebConfig(token=TOKEN), [
        ("/static/index.html", {}), ("/static/../server.py", {}),
        ("/static/%2e%2e/server.py", {}), ("/static/", {}), ("/server.py", {}),
        ("/favicon.ico", {})]))
    assert got == [200, 404, 404, 403, 404, 204]
