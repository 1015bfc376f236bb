"""The demo keeps the documented endpoint (tcp/127.0.0.1:7447) whenever it can be listened
on, also right after a previous run whose connections wait out TIME_WAIT there; when
another program holds it, the demo says so loudly and which port it took instead."""

from __future__ import annotations

import json
import socket

import pytest
import zenoh

from dispatcher.tools.demo import _port_or_say, free_port


def _port_in_time_wait() -> int:
    """A port whose listener is closed and whose last connection, closed by its side
    first, waits out TIME_WAIT, as 7447 does right after a demo."""
    listener = socket.create_server(("127.0.0.1", 0))
    port = int(listener.getsockname()[1])
    client = socket.create_connection(("127.0.0.1", port))
    conn, _ = listener.accept()
    conn.close()  # the listening side closes first: its end goes to TIME_WAIT
    client.close()
    listener.close()
    return port


def test_a_port_in_time_wait_is_kept_and_zenoh_listens_on_it() -> None:
    port = _port_in_time_wait()
    with socket.socket() as plain, pytest.raises(OSError):
        plain.bind(("127.0.0.1", port))  # the old check: "busy"
    assert free_port(port) == port
    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    with zenoh.open(conf):
        pass  # the listener the demo starts can have it


def test_a_port_listened_on_is_left_and_said_loudly(capsys: pytest.CaptureFixture[str]) -> None:
    with socket.create_server(("127.0.0.1", 0)) as other:
        port = int(other.getsockname()[1])
        assert _port_or_say(port, "zenoh endpoint") != port
    err = capsys.readouterr().err
    assert f"WARNING: port {port} on 127.0.0.1 is taken by another program" in err
    assert "Outside tools must use port" in err


def test_a_free_port_is_taken_silently(capsys: pytest.CaptureFixture[str]) -> None:
    port = _port_in_time_wait()
    assert _port_or_say(port, "zenoh endpoint") == port
    assert capsys.readouterr().err == ""
