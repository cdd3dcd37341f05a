import subprocess
import sys

import pytest

from lodsprite.distributed.netns import CLIENT_IP, SERVER_IP, available, two_hosts

REASON = available()


def namespaces() -> str:
    return subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout


@pytest.mark.skipif(REASON is not None, reason=f"network namespaces: {REASON}")
def test_two_hosts_reach_each_other_and_are_removed_even_on_failure():
    with pytest.raises(RuntimeError), two_hosts("100mbit") as hosts:
        assert hosts.client_ns in namespaces() and hosts.server_ns in namespaces()
        route = subprocess.run(hosts.server(["ip", "addr"]), capture_output=True, text=True)
        assert SERVER_IP in route.stdout and CLIENT_IP not in route.stdout
        # Nothing listens on port 9: a refused connection proves the server host answers.
        probe = subprocess.run(hosts.client([sys.executable, "-c",
                                             f"import socket; socket.create_connection("
                                             f"('{SERVER_IP}', 9), 3)"]),
                               capture_output=True, text=True)
        assert "ConnectionRefusedError" in probe.stderr
        raise RuntimeError("fail inside the block")
    assert hosts.client_ns not in namespaces() and hosts.server_ns not in namespaces()
