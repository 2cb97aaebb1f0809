"""Stopping the daemon: Ctrl-C ends ``dcobserver run`` with status 0, never an abort.

``dcobserver run`` used to abort now and then on Ctrl-C ("FATAL: exception not
rethrown", status -6): zenoh-python runs a Python callback (the ``latest``
queryable's) in a thread of its own, daemonic when declared from a daemon thread,
which waits inside Zenoh with the GIL released. When the interpreter finalized
before that thread had left Zenoh, CPython ended it with pthread_exit, and the
unwinding through Rust frames aborted the process. The publisher now serves the
queryable's channel from a thread of its own and joins it on close.
"""

from __future__ import annotations

import signal
import threading
import time
from pathlib import Path

import pytest
import zenoh

from observer.config import ZenohConfig
from observer.service.zenohpub import ZenohPublisher
from tests.peers import REPO, free_port


def _client(port: int) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{port}"]')
    return zenoh.open(conf)


def _latest(session: zenoh.Session) -> list[bytes]:
    replies = session.get("dcobserver/**/latest", timeout=5.0)
    return [r.ok.payload.to_bytes() for r in replies if r.ok is not None]


def test_the_publisher_leaves_no_thread_inside_zenoh_when_closed():
    port = free_port()
    config = ZenohConfig(listen=[f"tcp/127.0.0.1:{port}"], multicast_scouting=False)
    before = set(threading.enumerate())
    publisher = ZenohPublisher(config, "drive1")
    publisher.start()
    try:
        deadline = time.monotonic() + 30
        while publisher.health()["state"] != "open":
            assert time.monotonic() < deadline, publisher.health()
            threading.Event().wait(0.01)
        assert publisher.publish("estimate", b'{"index": 7}')
        client = _client(port)
        try:
            assert _latest(client) == [b'{"index": 7}']  # the queryable answers
        finally:
            client.close()
        # Every thread started for the session is the publisher's own, none of Zenoh's
        # callback threads (which the interpreter would finalize inside Zenoh).
        started = set(threading.enumerate()) - before
        assert started <= set(publisher.threads()), [t.name for t in started]
    finally:
        publisher.close()
    assert not [t.name for t in publisher.threads() if t.is_alive()]
    assert set(threading.enumerate()) <= before


@pytest.mark.slow
def test_ctrl_c_after_the_first_estimate_exits_with_status_0(tmp_path: Path, children):
    """The README's demo, stopped by SIGINT once it has published, while a client keeps
    querying ``latest``: exit status 0, no abort, the log finished. Several times."""
    for attempt in range(3):
        folder = tmp_path / str(attempt)
        folder.mkdir()
        port = free_port()
        text = (REPO / "config" / "demo.toml").read_text()
        text = text.replace('"../replay/data/demo.mcap"', f'"{REPO}/replay/data/demo.mcap"')
        text = text.replace("tcp/127.0.0.1:7447", f"tcp/127.0.0.1:{port}")
        text = text.replace('"../dcobserver-logs"', f'"{folder}/logs"')
        config = folder / "demo.toml"
        config.write_text(text)
        daemon = children(["run", "--config", str(config)])
        daemon.wait_line(r"zenoh: publishing on", timeout=120)
        client = _client(port)
        stop = threading.Event()

        def query(session: zenoh.Session = client, stop: threading.Event = stop) -> None:
            while not stop.is_set():
                _latest(session)

        querying = threading.Thread(target=query, daemon=True)
        querying.start()
        try:
            daemon.wait_line(r"window \d+ t=", timeout=120)  # the first estimate
            daemon.proc.send_signal(signal.SIGINT)
            code = daemon.proc.wait(60)
        finally:
            stop.set()
            querying.join(30)
            client.close()
        err = "".join(daemon.stderr)
        assert code == 0, (attempt, code, err[-3000:])
        assert "FATAL" not in err and "Traceback" not in err, err[-3000:]
        assert "MCAP log: finished" in err
