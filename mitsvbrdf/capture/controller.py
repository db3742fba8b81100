"""Host side of the capture bench's serial-line controller (shutter, trigger, stages, turntable).

The bench controller (a microcontroller on a USB serial port, or anything that speaks the same
lines over TCP) drives the camera's trigger and exposure time and the motion stages. This module
is the host's side; :mod:`.fake_controller` is a device written to the same protocol, with fault
injection, for tests and for dry runs without hardware.

Protocol
========

Transport
    Any byte stream that :func:`serial.serial_for_url` opens: a serial device (``/dev/ttyUSB0``,
    a pty slave's name), ``socket://host:port`` (TCP), ``loop://`` (pyserial's loopback). The
    baud rate matters only for real serial lines (default 115200, 8N1).

Framing
    One frame per line, printable ASCII, at most :data:`MAX_LINE` (255) bytes before the ``\\n``::

        <seq> <FIELD> [<FIELD> ...]*<CS>\\n

    Fields are separated by single spaces and are non-empty runs of printable ASCII (0x21-0x7E)
    other than ``*``. A trailing ``\\r`` before the ``\\n`` is tolerated on reading and never
    written. ``seq`` is a decimal integer 1..9999 with no sign and no leading zeros needed (the
    reader accepts them).

Checksum (NMEA style)
    ``CS`` is the XOR of every byte before the ``*`` (the seq, the spaces and the fields), written
    as exactly two hexadecimal digits, upper case (readers also accept lower case). A line whose
    checksum does not match, that has no ``*`` or more than one, that is not ASCII or that does
    not parse is discarded whole; the receiver never guesses what it meant.

Requests (host -> device): ``<seq> <COMMAND> [args...]*<CS>``

    ========================  =================================================================
    ``PING``                  Identify. Reply data: an identification string, e.g.
                              ``mitsvbrdf-fake 1`` (name and protocol version).
    ``SHUTTER <seconds>``     Set the exposure time, seconds (decimal, ``1e-3`` form allowed),
                              > 0. Reply: ``OK``.
    ``TRIGGER``               Fire the camera with the current exposure. The reply ``OK`` comes
                              after the exposure has completed, so the host waits at least the
                              exposure time for it.
    ``MOVE <axis> <pos>``     Move one axis to an absolute position: ``x``, ``y``, ``z`` in
                              metres, ``turntable`` in degrees. The reply ``OK`` comes after the
                              move has finished.
    ``HOME``                  Home every axis (positions become 0). Reply ``OK`` when done.
    ``STATUS``                Reply data: ``key=value`` fields, e.g. ``exposure=0.01 x=0.0
                              y=0.0 z=0.0 turntable=90.0 homed=1 triggers=3``. Keys the host
                              does not know are kept, not rejected (devices may add more).
    ========================  =================================================================

Replies (device -> host)
    ``<seq> OK [data...]*<CS>`` on success, ``<seq> ERR <code> <message...>*<CS>`` on failure,
    where ``seq`` is the request's. ``code`` is one upper-case word; the message is free text
    (printable ASCII words, no ``*``). Codes used by the reference device:

    ==========  ========================================================================
    ``BADCMD``  unknown command
    ``BADARG``  wrong number of arguments, or an argument that does not parse
    ``RANGE``   a value outside the device's limits (exposure, stage travel)
    ``FAULT``   the device failed to carry out a valid command (jammed stage, camera error)
    ==========  ========================================================================

    Devices may use other codes; the host passes any code on unchanged
    (:class:`ControllerCommandError`). A request that fails its checksum or does not parse gets
    no reply at all (there is no trustworthy seq to answer to); the host's retry covers it.

Sequence numbers and idempotency
    The host numbers its requests 1, 2, ... 9999, then 1 again. A new :class:`SerialController`
    starts at a random number, so that a fresh session is unlikely to reuse the number the device
    remembers from the previous session. The device remembers the last request it executed (its
    seq and fields) and the reply it sent. When the same request arrives again with the same
    seq, it is *not* executed again: the remembered reply is re-sent. This makes retries safe:
    when an acknowledgement is lost, resending the frame must not fire the camera a second time
    or move a stage twice. (The reference device compares the whole request, not only the seq,
    so a new host that happens to reuse the remembered seq for a different command still gets it
    executed; only an identical command with an identical seq is taken as a repeat.)

Host behaviour (:class:`SerialController`)
    * Send the frame, then read lines until a valid reply carrying the same seq arrives or
      ``timeout`` seconds pass. Ignored on the way (counted in :attr:`SerialController.stats`):
      lines that are not valid frames (``garbage``: bad checksum, no ``*``, not ASCII, not
      parsable, overlong), and valid frames that are not the awaited reply (``stale``: replies
      with another seq, e.g. a late answer to an earlier request that was already retried, and
      requests, e.g. our own echo on a loopback).
    * No reply within ``timeout``: resend the *same* frame (same seq) up to ``retries`` times
      (``stats["retries"]``), then raise :class:`ControllerTimeout` naming the command, the port
      URL and the number of attempts. ``TRIGGER`` waits ``timeout`` plus the exposure time last
      set through this controller.
    * ``ERR``: raise :class:`ControllerCommandError` (``.code``, ``.message``) at once, without
      retrying (the device did answer; repeating the request would get the same answer).
    * The port fails (:class:`serial.SerialException`, :class:`OSError`, the peer closing a TCP
      connection, a pty going away): close it, try to reopen the URL up to ``reconnect`` times
      per command, ``reconnect_delay`` seconds apart (``stats["reconnects"]`` counts successful
      reopens), and resend the same frame (same seq, so a command the device executed just
      before the link went down is not executed twice). When reopening fails, raise
      :class:`ControllerDisconnected` naming the URL. The next command tries to reopen again.
    * Arguments are checked before anything is sent (``ValueError``): a bad request never
      reaches the device.

All errors of this module subclass :class:`ControllerError` (a ``RuntimeError``: these are
failures of the bench, not of the caller's input, which raise ``ValueError``).
"""

from __future__ import annotations

import math
import random
import re
import threading
import time
from types import TracebackType

import serial

MAX_LINE = 255
"""Longest frame in bytes, not counting the line end."""
SEQ_MAX = 9999
"""Sequence numbers run 1..SEQ_MAX and then wrap to 1."""
AXES = ("x", "y", "z", "turntable")
"""Axes of ``MOVE``: x, y, z in metres, turntable in degrees."""

_FIELD = re.compile(rb"[\x21-\x29\x2b-\x7e]+")  # printable ASCII without space and '*'
_COMMAND = re.compile(r"[A-Z][A-Z0-9_]*")
_PORT_ERRORS = (serial.SerialException, OSError)
_POLL_S = 0.05  # the port's read timeout: how often the reply deadline is checked


class ControllerError(RuntimeError):
    """Base class of the bench controller's failures."""


class ControllerTimeout(ControllerError):
    """No valid reply after every retry."""


class ControllerCommandError(ControllerError):
    """The device answered ``ERR``. ``code``: the device's error code (one word, e.g. ``RANGE``);
    ``message``: its text."""

    def __init__(self, code: str, message: str, *, command: str = "", url: str = "") -> None:
        super().__init__(f"{command} on {url} failed: ERR {code} {message}".strip())
        self.code = code
        self.message = message


class ControllerDisconnected(ControllerError):
    """The port failed and could not be reopened."""


def checksum(payload: str) -> str:
    """Two upper-case hex digits: the XOR of the bytes of ``payload`` (ASCII), NMEA style."""
    cs = 0
    for b in payload.encode("ascii"):
        cs ^= b
    return f"{cs:02X}"


def _field(value: object) -> str:
    # repr of a float is the shortest text that reads back to the same float (0.1, 1e-05)
    return repr(value) if isinstance(value, float) else str(value)


def encode_frame(seq: int, *fields: object) -> bytes:
    """The line ``<seq> <fields...>*<CS>\\n`` as bytes.

    Floats are written with ``repr`` (round trip exact), everything else with ``str``. Raises
    ``ValueError`` for a seq outside 1..9999, no fields, a field that is empty or holds a space,
    ``*`` or anything but printable ASCII, or a frame longer than :data:`MAX_LINE`.
    """
    if isinstance(seq, bool) or not isinstance(seq, int) or not 1 <= seq <= SEQ_MAX:
        raise ValueError(f"seq must be an int in 1..{SEQ_MAX}, got {seq!r}")
    if not fields:
        raise ValueError("a frame needs at least one field (the command or OK/ERR)")
    texts = [_field(f) for f in fields]
    for t in texts:
        if not t.isascii() or not _FIELD.fullmatch(t.encode("ascii")):
            raise ValueError(f"frame field {t!r} must be non-empty printable ASCII without spaces or '*'")
    payload = " ".join([str(seq), *texts])
    line = f"{payload}*{checksum(payload)}"
    if len(line) > MAX_LINE:
        raise ValueError(f"frame of {len(line)} bytes is longer than {MAX_LINE}")
    return (line + "\n").encode("ascii")


def decode_frame(line: bytes) -> tuple[int, list[str]] | None:
    """``(seq, fields)`` of a received line (with or without its ``\\r\\n``), or None when it is
    not a valid frame: not ASCII, overlong, no or several ``*``, checksum not two hex digits or
    not matching, seq not a decimal in 1..9999, no field after the seq, or a malformed field."""
    line = bytes(line).rstrip(b"\n").rstrip(b"\r")
    if len(line) > MAX_LINE or line.count(b"*") != 1:
        return None
    payload, _, cs = line.partition(b"*")
    if len(cs) != 2 or not all(c in b"0123456789abcdefABCDEF" for c in cs):
        return None
    parts = payload.split(b" ")
    if len(parts) < 2 or not all(_FIELD.fullmatch(p) for p in parts):
        return None  # also rejects non-ASCII bytes, double spaces and control characters
    text = payload.decode("ascii")
    if checksum(text) != cs.decode("ascii").upper():
        return None
    seq_text, *fields = text.split(" ")
    if not seq_text.isdigit() or not 1 <= int(seq_text) <= SEQ_MAX:
        return None
    return int(seq_text), fields


def _finite(name: str, value: float) -> float:
    if isinstance(value, bool):
        raise ValueError(f"{name} must be a number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return v


class SerialController:
    """The host's end of the bench controller's line protocol (see the module docstring).

    Args:
        url: anything :func:`serial.serial_for_url` opens: ``/dev/ttyUSB0``, a pty slave's path,
            ``socket://host:port``, ``loop://``.
        baudrate: line speed in baud (serial devices only).
        timeout: seconds to wait for the reply to one attempt (> 0). ``TRIGGER`` adds the
            exposure time; slow moves can pass their own ``timeout``.
        retries: resends of the same frame after a timeout (>= 0) before
            :class:`ControllerTimeout`.
        reconnect: attempts to reopen a failed port, per command (>= 0; 0: fail at once with
            :class:`ControllerDisconnected`).
        reconnect_delay: seconds to wait before each reopen attempt.
        first_seq: seq of the first request (1..9999); None: random (see the module docstring).

    The port is opened here (:class:`ControllerDisconnected` if it cannot be). Calls are
    serialised by a lock, so several threads may share one controller.

    Attributes:
        stats: counters since construction: ``sent`` (frames written, retries included),
            ``garbage`` (invalid lines ignored), ``stale`` (valid frames that were not the awaited
            reply), ``retries`` (resends after a timeout), ``reconnects`` (successful reopens).
    """

    def __init__(self, url: str, *, baudrate: int = 115200, timeout: float = 0.5, retries: int = 3,
                 reconnect: int = 3, reconnect_delay: float = 0.2, first_seq: int | None = None) -> None:
        if not (timeout > 0 and math.isfinite(timeout)):
            raise ValueError(f"timeout must be a positive number of seconds, got {timeout!r}")
        if retries < 0 or reconnect < 0 or reconnect_delay < 0:
            raise ValueError(f"retries, reconnect and reconnect_delay must be >= 0, got "
                             f"{retries!r}, {reconnect!r}, {reconnect_delay!r}")
        if first_seq is not None and not 1 <= first_seq <= SEQ_MAX:
            raise ValueError(f"first_seq must be in 1..{SEQ_MAX}, got {first_seq!r}")
        self.url = url
        self.baudrate = baudrate
        self.timeout = float(timeout)
        self.retries = int(retries)
        self.reconnect = int(reconnect)
        self.reconnect_delay = float(reconnect_delay)
        self.stats: dict[str, int] = {"sent": 0, "garbage": 0, "stale": 0, "retries": 0, "reconnects": 0}
        self._seq = first_seq if first_seq is not None else random.SystemRandom().randint(1, SEQ_MAX)
        self._exposure = 0.0  # last exposure set through this controller, seconds
        self._buf = bytearray()
        self._lock = threading.RLock()
        self._closed = False
        try:
            self._port: serial.SerialBase | None = self._open()
        except _PORT_ERRORS as exc:
            raise ControllerDisconnected(f"cannot open the bench controller at {url}: {exc}") from exc

    # -- commands -----------------------------------------------------------------------------

    def command(self, name: str, *args: object, timeout: float | None = None) -> list[str]:
        """Send ``name args...`` and return the reply's data fields (after ``OK``).

        ``timeout``: seconds per attempt for this command (default: the controller's). Raises
        ``ValueError`` for a malformed command (nothing is sent), :class:`ControllerCommandError`
        on ``ERR``, :class:`ControllerTimeout`, :class:`ControllerDisconnected`.
        """
        if not isinstance(name, str) or not _COMMAND.fullmatch(name):
            raise ValueError(f"command name must be upper-case letters, digits or _, got {name!r}")
        if timeout is not None and not (timeout > 0 and math.isfinite(timeout)):
            raise ValueError(f"timeout must be a positive number of seconds, got {timeout!r}")
        with self._lock:
            if self._closed:
                raise ControllerError(f"the controller for {self.url} is closed")
            seq = self._seq
            frame = encode_frame(seq, name, *args)  # ValueError here: nothing sent, seq not used
            self._seq = seq % SEQ_MAX + 1
            fields = self._exchange(seq, frame, name, self.timeout if timeout is None else float(timeout))
        if fields[0] == "ERR":
            raise ControllerCommandError(fields[1], " ".join(fields[2:]), command=name, url=self.url)
        return fields[1:]

    def ping(self) -> str:
        """The device's identification string."""
        return " ".join(self.command("PING"))

    def shutter(self, seconds: float) -> None:
        """Set the exposure time (seconds, finite, > 0)."""
        s = _finite("exposure time", seconds)
        if s <= 0:
            raise ValueError(f"exposure time must be > 0 s, got {seconds!r}")
        self.command("SHUTTER", s)
        self._exposure = s

    def trigger(self, *, timeout: float | None = None) -> None:
        """Fire the camera; returns once the exposure has completed. Waits ``timeout`` (default
        the controller's) plus the last exposure time set through :meth:`shutter`."""
        base = self.timeout if timeout is None else float(timeout)
        self.command("TRIGGER", timeout=base + self._exposure)

    def move(self, axis: str, position: float, *, timeout: float | None = None) -> None:
        """Move ``axis`` (x, y, z: metres; turntable: degrees) to ``position``; returns when the
        move has finished (``timeout``: seconds per attempt, for long moves)."""
        if axis not in AXES:
            raise ValueError(f"unknown axis {axis!r}; axes are {', '.join(AXES)}")
        self.command("MOVE", axis, _finite(f"{axis} position", position), timeout=timeout)

    def home(self, *, timeout: float | None = None) -> None:
        """Home every axis; returns when done."""
        self.command("HOME", timeout=timeout)

    def status(self) -> dict[str, str]:
        """The device's ``key=value`` status fields (a field without ``=`` maps to "")."""
        out: dict[str, str] = {}
        for f in self.command("STATUS"):
            key, _, value = f.partition("=")
            out[key] = value
        return out

    def close(self) -> None:
        """Close the port (idempotent); later commands raise :class:`ControllerError`."""
        with self._lock:
            self._closed = True
            self._close_port()

    def __enter__(self) -> SerialController:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    # -- transport ----------------------------------------------------------------------------

    def _open(self) -> serial.SerialBase:
        # the read timeout is only the polling period: the reply deadline is kept here
        return serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=min(self.timeout, _POLL_S))

    def _close_port(self) -> None:
        port, self._port = self._port, None
        self._buf.clear()
        if port is None:
            return
        # pyserial 3.5's socket:// close skips closing the socket when shutdown() fails, which it
        # does once the peer has gone: close it ourselves so reconnects do not leak descriptors
        sock = getattr(port, "_socket", None)
        try:
            port.close()
        except _PORT_ERRORS:
            pass  # already broken; nothing left to release
        if sock is not None and hasattr(sock, "close"):
            sock.close()

    def _exchange(self, seq: int, frame: bytes, name: str, timeout: float) -> list[str]:
        """Send ``frame`` until its reply arrives; returns the reply's fields from OK/ERR on."""
        attempts = timeouts = 0
        reopen_budget = self.reconnect
        while True:
            try:
                if self._port is None:  # a previous command lost the port
                    raise serial.SerialException("port is not open")
                self._port.write(frame)
                self._port.flush()
                attempts += 1
                self.stats["sent"] += 1
                reply = self._await_reply(seq, time.monotonic() + timeout)
            except _PORT_ERRORS as exc:
                reopen_budget = self._reopen(exc, name, reopen_budget)
                continue
            if reply is not None:
                return reply
            timeouts += 1
            if timeouts > self.retries:
                raise ControllerTimeout(f"{name}: no reply from {self.url} after {attempts} attempt"
                                        f"{'s' if attempts != 1 else ''} ({timeout:g} s each)")
            self.stats["retries"] += 1

    def _reopen(self, cause: BaseException, name: str, budget: int) -> int:
        """Reopen the URL using at most ``budget`` attempts; returns the budget left."""
        self._close_port()
        tried = 0
        while budget > 0:
            budget -= 1
            tried += 1
            time.sleep(self.reconnect_delay)
            try:
                self._port = self._open()
            except _PORT_ERRORS as exc:
                cause = exc
                continue
            self.stats["reconnects"] += 1
            return budget
        raise ControllerDisconnected(f"{name}: lost the bench controller at {self.url} ({cause}); "
                                     f"reopening failed after {tried} attempt{'s' if tried != 1 else ''}")

    def _await_reply(self, seq: int, deadline: float) -> list[str] | None:
        """Fields (from OK/ERR on) of the first valid reply to ``seq``, or None at the deadline."""
        while (line := self._read_line(deadline)) is not None:
            frame = decode_frame(line)
            if frame is None:
                self.stats["garbage"] += 1
                continue
            rseq, fields = frame
            if rseq != seq or fields[0] not in ("OK", "ERR"):
                self.stats["stale"] += 1  # an old reply, or a request (our own echo)
                continue
            if fields[0] == "ERR" and len(fields) < 2:
                self.stats["garbage"] += 1  # ERR without a code is not a valid reply
                continue
            return fields
        return None

    def _read_line(self, deadline: float) -> bytes | None:
        """Next line (without ``\\n``), or None once ``deadline`` (monotonic s) has passed.
        Port errors propagate."""
        port = self._port
        assert port is not None
        while True:
            nl = self._buf.find(b"\n")
            if nl >= 0:
                line = bytes(self._buf[:nl])
                del self._buf[:nl + 1]
                return line
            if len(self._buf) > MAX_LINE + 2:
                # a line this long cannot be a frame: drop what we have (its tail, when the
                # newline comes, is counted as one more garbage line)
                self.stats["garbage"] += 1
                self._buf.clear()
            if time.monotonic() >= deadline:
                return None
            self._buf += port.read(max(1, port.in_waiting))
