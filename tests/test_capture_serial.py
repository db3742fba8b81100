"""The bench controller's line protocol: framing, retries, idempotency, reconnects.

No hardware: pyserial's ``loop://``, a pty pair served by the fake device, and ``socket://`` to
the fake's TCP server. Timeouts are short (0.1-0.2 s) so every test takes well under 3 s.
"""

from __future__ import annotations

import math
import os
import sys

import pytest

pytest.importorskip("serial")

from mitsvbrdf.capture.controller import (ControllerCommandError, ControllerDisconnected, ControllerError,
                                          ControllerTimeout, SerialController, checksum, decode_frame,
                                          encode_frame)
from mitsvbrdf.capture.fake_controller import FakeControllerDevice

posix_only = pytest.mark.skipif(os.name != "posix" or not hasattr(os, "openpty"), reason="needs a POSIX pty")
FAST = {"timeout": 0.15, "retries": 2, "reconnect": 2, "reconnect_delay": 0.05}


def names(device: FakeControllerDevice) -> list[tuple[str, tuple[str, ...]]]:
    return [(name, args) for _, name, args in device.executed]


@pytest.fixture
def pty_bench():
    """Factory: ``make(**faults) -> (controller, device)`` on a fresh pty pair; all closed after."""
    made = []

    def make(first_seq: int | None = None, **faults):
        master, slave = os.openpty()
        dev = FakeControllerDevice(**faults)
        dev.serve_fd(master)
        ctl = SerialController(os.ttyname(slave), first_seq=first_seq, **FAST)
        made.append((ctl, dev, master, slave))
        return ctl, dev

    yield make
    for ctl, dev, master, slave in made:
        ctl.close()
        dev.stop()
        os.close(master)
        os.close(slave)


@pytest.fixture
def tcp_bench():
    """Factory: ``make(**faults) -> (controller, device, url)`` over TCP to the fake's server."""
    made = []

    def make(**faults):
        dev = FakeControllerDevice(**faults)
        port, _ = dev.serve_tcp()
        url = f"socket://127.0.0.1:{port}"
        ctl = SerialController(url, **FAST)
        made.append((ctl, dev))
        return ctl, dev, url

    yield make
    for ctl, dev in made:
        ctl.close()
        dev.stop()


# -- framing ----------------------------------------------------------------------------------

def test_checksum_is_xor_of_payload_bytes_in_upper_hex():
    assert checksum("") == "00"
    assert checksum("A") == "41"
    assert checksum("AB") == f"{ord('A') ^ ord('B'):02X}"
    assert checksum("1 PING") == "01"  # 0x31 ^ 0x20 ^ 0x50 ^ 0x49 ^ 0x4E ^ 0x47
    # the widely quoted NMEA example ($GPGGA ... *47): the same XOR as NMEA
    assert checksum("GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,") == "47"


def test_encode_decode_round_trip():
    line = encode_frame(42, "MOVE", "x", 0.125)
    assert line.endswith(b"\n") and b"*" in line
    assert decode_frame(line) == (42, ["MOVE", "x", "0.125"])
    assert decode_frame(line.rstrip(b"\n") + b"\r\n") == (42, ["MOVE", "x", "0.125"])
    assert float(decode_frame(encode_frame(1, "SHUTTER", 1 / 3))[1][1]) == 1 / 3  # floats exact


def test_encode_rejects_bad_fields_and_seq():
    for bad in ("two words", "a*b", "", "caf\u00e9", "tab\there"):
        with pytest.raises(ValueError):
            encode_frame(1, "MOVE", bad)
    for seq in (0, 10000, -1, True):
        with pytest.raises(ValueError):
            encode_frame(seq, "PING")


def test_decode_rejects_bad_checksum():
    line = encode_frame(7, "OK")
    wrong = line[:-3] + (b"00" if line[-3:-1] != b"00" else b"01") + b"\n"
    assert decode_frame(wrong) is None


def test_decode_rejects_missing_star():
    assert decode_frame(b"7 OK\n") is None
    assert decode_frame(b"7 OK 5A\n") is None


def test_decode_rejects_non_numeric_seq():
    payload = "x7 OK"
    assert decode_frame(f"{payload}*{checksum(payload)}\n".encode()) is None
    payload = "0 OK"  # seq 0 is outside 1..9999
    assert decode_frame(f"{payload}*{checksum(payload)}\n".encode()) is None


def test_decode_rejects_non_ascii():
    payload = "7 OK caf\u00e9".encode("latin-1")
    cs = 0
    for b in payload:
        cs ^= b
    assert decode_frame(payload + f"*{cs:02X}\n".encode()) is None
    assert decode_frame(b"\xff\xfe\x00garbage\n") is None


def test_decode_rejects_seq_only_frame():
    assert decode_frame(f"5*{checksum('5')}\n".encode()) is None


# -- loopback: our own echo is not an acknowledgement -------------------------------------------

def test_loopback_echo_is_not_an_acknowledgement():
    with SerialController("loop://", timeout=0.1, retries=2, reconnect=0) as ctl:
        with pytest.raises(ControllerTimeout) as err:
            ctl.ping()
    msg = str(err.value)
    assert "PING" in msg and "loop://" in msg and "3 attempts" in msg
    assert ctl.stats["retries"] == 2
    assert ctl.stats["sent"] == 3
    assert ctl.stats["stale"] + ctl.stats["garbage"] == 3  # one echo per attempt, all ignored


# -- pty with the fake device -----------------------------------------------------------------

@posix_only
def test_pty_commands_work_and_reach_the_device(pty_bench):
    ctl, dev = pty_bench()
    assert ctl.ping() == "mitsvbrdf-fake 1"
    ctl.shutter(0.02)
    ctl.move("x", 0.1)
    ctl.move("turntable", 90.0)
    ctl.trigger()
    status = ctl.status()
    assert dev.exposure == 0.02
    assert dev.position["x"] == 0.1 and dev.position["turntable"] == 90.0
    assert float(status["exposure"]) == 0.02 and float(status["turntable"]) == 90.0
    assert status["triggers"] == "1"
    assert names(dev) == [("PING", ()), ("SHUTTER", ("0.02",)), ("MOVE", ("x", "0.1")),
                          ("MOVE", ("turntable", "90.0")), ("TRIGGER", ()), ("STATUS", ())]
    assert ctl.stats["retries"] == 0 and ctl.stats["garbage"] == 0


@posix_only
def test_pty_home_zeroes_positions(pty_bench):
    ctl, dev = pty_bench()
    ctl.move("y", -0.2)
    ctl.home()
    assert dev.homed and dev.position == {"x": 0.0, "y": 0.0, "z": 0.0, "turntable": 0.0}


@posix_only
def test_pty_garbage_before_every_reply_is_ignored(pty_bench):
    ctl, dev = pty_bench(garbage_before_reply=4)
    ctl.shutter(0.01)
    ctl.trigger()
    ctl.move("z", 0.05)
    assert dev.position["z"] == 0.05 and dev.triggers == 1
    assert ctl.stats["garbage"] >= 3 * 3  # random bytes, bad checksum, no '*' per reply
    assert ctl.stats["stale"] >= 3  # a valid reply to another seq per reply
    assert ctl.stats["retries"] == 0


@posix_only
def test_pty_dropped_reply_is_retried_and_trigger_runs_once(pty_bench):
    ctl, dev = pty_bench(first_seq=100, drop_replies={101})
    ctl.shutter(0.01)  # seq 100
    ctl.trigger()      # seq 101: executed, reply dropped, resent, answered from memory
    assert ctl.stats["retries"] == 1
    assert names(dev) == [("SHUTTER", ("0.01",)), ("TRIGGER", ())]
    assert dev.triggers == 1


@posix_only
def test_pty_err_reply_raises_without_retry(pty_bench):
    ctl, dev = pty_bench(fail_commands={"TRIGGER": "JAM shutter jammed"})
    with pytest.raises(ControllerCommandError) as err:
        ctl.trigger()
    assert err.value.code == "JAM" and err.value.message == "shutter jammed"
    assert "TRIGGER" in str(err.value)
    assert ctl.stats["sent"] == 1 and ctl.stats["retries"] == 0
    assert dev.executed == [] and dev.triggers == 0


@posix_only
def test_pty_device_range_error_is_reported(pty_bench):
    ctl, dev = pty_bench()
    with pytest.raises(ControllerCommandError) as err:
        ctl.move("x", 2.0)  # beyond the fake's 0.5 m travel
    assert err.value.code == "RANGE"
    assert dev.position["x"] == 0.0


@posix_only
def test_pty_seq_wraps_from_9999_to_1(pty_bench):
    ctl, dev = pty_bench(first_seq=9999)
    ctl.ping()
    ctl.ping()
    assert [seq for seq, _, _ in dev.executed] == [9999, 1]


# -- the fake's idempotency, without a transport ------------------------------------------------

def test_fake_repeated_frame_is_answered_from_memory_not_executed():
    dev = FakeControllerDevice()
    frame = encode_frame(5, "TRIGGER")
    first = dev.handle_line(frame)
    again = dev.handle_line(frame)
    assert first == again and decode_frame(first[-1]) == (5, ["OK"])
    assert dev.triggers == 1 and len(dev.executed) == 1


def test_fake_same_seq_with_another_command_is_executed():
    dev = FakeControllerDevice()
    dev.handle_line(encode_frame(5, "TRIGGER"))
    dev.handle_line(encode_frame(5, "MOVE", "x", 0.1))  # a new host reusing the seq
    assert names(dev) == [("TRIGGER", ()), ("MOVE", ("x", "0.1"))]


def test_fake_ignores_corrupt_requests():
    dev = FakeControllerDevice()
    good = encode_frame(3, "TRIGGER")
    assert dev.handle_line(good[:-3] + b"ZZ\n") == []
    assert dev.executed == []


def test_fake_on_trigger_hook_runs_per_executed_trigger():
    dev = FakeControllerDevice()
    seen = []
    dev.on_trigger = lambda d: seen.append(d.exposure)
    dev.handle_line(encode_frame(1, "SHUTTER", 0.001))
    dev.handle_line(encode_frame(2, "TRIGGER"))
    dev.handle_line(encode_frame(2, "TRIGGER"))  # a repeat: no second frame
    assert seen == [0.001]


# -- TCP ----------------------------------------------------------------------------------------

def test_tcp_commands_work(tcp_bench):
    ctl, dev, _ = tcp_bench()
    assert ctl.ping() == "mitsvbrdf-fake 1"
    ctl.move("y", 0.25)
    assert ctl.status()["y"] == "0.25"
    assert dev.position["y"] == 0.25


def test_tcp_disconnect_is_recovered_without_repeating_or_losing_commands(tcp_bench):
    ctl, dev, _ = tcp_bench(disconnect_after=2)
    ctl.ping()
    ctl.shutter(0.01)  # executed, then the link drops before the reply
    ctl.trigger()
    ctl.move("turntable", 45.0)
    assert ctl.stats["reconnects"] >= 1
    assert names(dev) == [("PING", ()), ("SHUTTER", ("0.01",)), ("TRIGGER", ()),
                          ("MOVE", ("turntable", "45.0"))]
    assert dev.triggers == 1


def test_tcp_server_gone_raises_disconnected_naming_url(tcp_bench):
    ctl, dev, url = tcp_bench()
    ctl.ping()
    dev.stop()
    with pytest.raises((ControllerDisconnected, ControllerTimeout)) as err:
        ctl.ping()
    assert url in str(err.value)
    assert isinstance(err.value, ControllerError) and isinstance(err.value, RuntimeError)


def test_unreachable_url_raises_disconnected_at_open():
    dev = FakeControllerDevice()
    port, _ = dev.serve_tcp()
    dev.stop()  # the port is now closed
    url = f"socket://127.0.0.1:{port}"
    with pytest.raises(ControllerDisconnected, match=url.replace(".", r"\.")):
        SerialController(url, **FAST)


# -- bad input never reaches the wire -----------------------------------------------------------

@pytest.mark.parametrize("call", [
    lambda c: c.move("w", 0.1),
    lambda c: c.move("x", math.inf),
    lambda c: c.move("turntable", math.nan),
    lambda c: c.shutter(-0.01),
    lambda c: c.shutter(0.0),
    lambda c: c.shutter(math.nan),
    lambda c: c.command("MOVE", "x y"),
    lambda c: c.command("move"),
], ids=["unknown-axis", "inf-position", "nan-angle", "negative-exposure", "zero-exposure",
        "nan-exposure", "space-in-arg", "lower-case-command"])
def test_bad_input_raises_before_sending(call):
    with SerialController("loop://", **FAST) as ctl:
        with pytest.raises(ValueError):
            call(ctl)
        assert ctl.stats["sent"] == 0
        assert ctl._port.in_waiting == 0  # loop:// would echo any byte written


def test_closed_controller_refuses_commands():
    ctl = SerialController("loop://", **FAST)
    ctl.close()
    ctl.close()  # idempotent
    with pytest.raises(ControllerError, match="closed"):
        ctl.ping()


@pytest.mark.skipif(sys.platform == "win32", reason="no pty")
def test_fake_command_line_help_runs():
    from mitsvbrdf.capture.fake_controller import main

    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
