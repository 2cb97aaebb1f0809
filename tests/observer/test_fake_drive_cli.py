"""``dcobserver fake-drive``: help for each protocol, one-line errors for bad input."""

from __future__ import annotations

import pytest

from observer.cli import main


@pytest.mark.parametrize("protocol", ["serial", "can", "modbus"])
def test_help_of_each_protocol(protocol, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["fake-drive", protocol, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "--speedup" in out and "--seed" in out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["fake-drive", "serial", "--rate", "0"], "--rate and --speedup must be > 0"),
        (["fake-drive", "serial", "--rate", "8000"], "more than --baud 921600"),
        (["fake-drive", "can", "--interface", "virtual"], "only its own process"),
        (["fake-drive", "can", "--interface", "nonexistent-if"], "cannot open CAN"),
        (["fake-drive", "modbus", "--stall-every", "-1"], "must be >= 0"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err


def test_modbus_port_in_use_is_a_one_line_error(capsys):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        assert main(["fake-drive", "modbus", "--port", str(port)]) == 2
    err = capsys.readouterr().err.strip()
    assert "cannot listen" in err and "Traceback" not in err
