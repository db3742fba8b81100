"""A software bench controller speaking the protocol of :mod:`.controller`, with fault injection.

Tests use it on a pty (:meth:`FakeControllerDevice.serve_fd`) or over TCP
(:meth:`FakeControllerDevice.serve_tcp`); a capture session can run against it with a simulated
camera hooked to :attr:`FakeControllerDevice.on_trigger`. From the command line::

    python -m mitsvbrdf.capture.fake_controller --tcp 5555      # prints socket://127.0.0.1:5555
    python -m mitsvbrdf.capture.fake_controller --pty           # prints the pty slave's path

Limits of the simulated bench (replies ``ERR RANGE`` outside them): exposure 0 < t <= 60 s;
x, y, z within +-0.5 m; the turntable takes any finite angle (degrees). ``TRIGGER`` takes the
exposure time (it sleeps), every command takes ``delay`` more.
"""

from __future__ import annotations

import argparse
import errno
import math
import os
import random
import select
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterable

from .controller import AXES, decode_frame, encode_frame

IDENT = ("mitsvbrdf-fake", "1")
"""PING reply: device name and protocol version."""
EXPOSURE_MAX = 60.0
"""Longest exposure the fake accepts, seconds."""
TRAVEL = {"x": (-0.5, 0.5), "y": (-0.5, 0.5), "z": (-0.5, 0.5), "turntable": (-math.inf, math.inf)}
"""Limits of each axis (metres; degrees for the turntable)."""
_POLL_S = 0.05  # how often serving threads look at the stop flag


def _words(text: str) -> list[str]:
    """Free text as protocol fields: printable ASCII words, '*' and the rest replaced by '?'."""
    clean = "".join(c if 0x21 <= ord(c) <= 0x7E and c != "*" else ("?" if not c.isspace() else " ")
                    for c in text)
    return clean.split() or ["-"]


class _CommandFailed(Exception):
    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code, self.message = code, message


class FakeControllerDevice:
    """The device side of the bench protocol, with faults to inject.

    Args:
        garbage_before_reply: lines of junk sent before every reply (cycling through: random
            non-ASCII bytes, a reply to the same seq with a wrong checksum, a line without ``*``,
            a well-formed reply to another seq).
        drop_replies: seqs whose *first* reply is not sent (the command is executed); a resend
            of the same frame gets the remembered reply.
        disconnect_after: close the TCP connection, without sending the reply, once this many
            commands have been executed (once; the next connection is served normally). No
            effect on a pty, which has no connection to drop.
        delay: extra seconds every command takes before its reply.
        fail_commands: command name -> ``"CODE [message...]"``; that command fails with
            ``ERR CODE message`` (default message "injected fault") and is not executed.

    Attributes:
        executed: ``(seq, name, args)`` of every command executed successfully, in order (appended
            under a lock; repeats answered from memory are not in it).
        exposure: current exposure time, seconds.
        position: current position per axis (x, y, z metres; turntable degrees).
        homed: whether HOME has run.
        on_trigger: called as ``on_trigger(device)`` on each executed TRIGGER, after the exposure
            time and before the reply; an exception in it makes the reply ``ERR FAULT``.
    """

    def __init__(self, *, garbage_before_reply: int = 0, drop_replies: Iterable[int] = frozenset(),
                 disconnect_after: int | None = None, delay: float = 0.0,
                 fail_commands: dict[str, str] | None = None, seed: int = 0) -> None:
        self.garbage_before_reply = int(garbage_before_reply)
        self.drop_replies = frozenset(drop_replies)
        self.disconnect_after = disconnect_after
        self.delay = float(delay)
        self.fail_commands = dict(fail_commands or {})
        self.executed: list[tuple[int, str, tuple[str, ...]]] = []
        self.exposure = 0.01
        self.position: dict[str, float] = {axis: 0.0 for axis in AXES}
        self.homed = False
        self.triggers = 0
        self.on_trigger: Callable[[FakeControllerDevice], object] | None = None
        self._lock = threading.RLock()  # RLock: on_trigger may read the device
        self._last: tuple[tuple[int, list[str]], bytes] | None = None  # (request, its reply)
        self._dropped: set[int] = set()
        self._disconnect_pending = False
        self._disconnected = False
        self._rng = random.Random(seed)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    # -- protocol -----------------------------------------------------------------------------

    def handle_line(self, line: bytes) -> list[bytes]:
        """Process one received line; returns the byte strings to send back (junk lines, then
        the reply), or [] for an invalid request (no seq to answer to) or a dropped reply."""
        with self._lock:
            frame = decode_frame(line)
            if frame is None:
                return []
            seq, fields = frame
            if self._last is not None and self._last[0] == (seq, fields):
                reply = self._last[1]  # a repeat: answer from memory, do not execute again
            else:
                reply = self._execute(seq, fields[0], tuple(fields[1:]))
                self._last = ((seq, fields), reply)
                if seq in self.drop_replies and seq not in self._dropped:
                    self._dropped.add(seq)
                    return []
            return [*self._garbage(seq), reply]

    def _execute(self, seq: int, name: str, args: tuple[str, ...]) -> bytes:
        if self.delay > 0:
            time.sleep(self.delay)
        try:
            if name in self.fail_commands:
                code, _, message = self.fail_commands[name].strip().partition(" ")
                raise _CommandFailed(code or "FAULT", message or "injected fault")
            handler = getattr(self, f"_cmd_{name.lower()}", None)
            if handler is None:
                raise _CommandFailed("BADCMD", f"unknown command {name}")
            data = handler(*args) if _arity_ok(handler, args) else _bad_args(name, args)
        except _CommandFailed as exc:
            return encode_frame(seq, "ERR", *_words(exc.code)[:1], *_words(exc.message))
        self.executed.append((seq, name, args))
        if self.disconnect_after is not None and not self._disconnected \
                and len(self.executed) >= self.disconnect_after:
            self._disconnect_pending = True
        return encode_frame(seq, "OK", *data)

    def _cmd_ping(self) -> list[str]:
        return list(IDENT)

    def _cmd_shutter(self, seconds: str) -> list[str]:
        s = _number("SHUTTER", seconds)
        if not 0 < s <= EXPOSURE_MAX:
            raise _CommandFailed("RANGE", f"exposure {s!r} s outside (0, {EXPOSURE_MAX:g}]")
        self.exposure = s
        return []

    def _cmd_trigger(self) -> list[str]:
        time.sleep(self.exposure)  # the reply comes after the exposure
        if self.on_trigger is not None:
            try:
                self.on_trigger(self)
            except Exception as exc:  # noqa: BLE001 - any camera failure becomes a device fault
                raise _CommandFailed("FAULT", f"camera failed: {exc}") from exc
        self.triggers += 1
        return []

    def _cmd_move(self, axis: str, position: str) -> list[str]:
        if axis not in TRAVEL:
            raise _CommandFailed("BADARG", f"unknown axis {axis}")
        p = _number("MOVE", position)
        lo, hi = TRAVEL[axis]
        if not lo <= p <= hi:
            raise _CommandFailed("RANGE", f"{axis} {p!r} outside [{lo:g}, {hi:g}]")
        self.position[axis] = p
        return []

    def _cmd_home(self) -> list[str]:
        self.position = {axis: 0.0 for axis in AXES}
        self.homed = True
        return []

    def _cmd_status(self) -> list[str]:
        return [f"exposure={self.exposure!r}", *(f"{a}={p!r}" for a, p in self.position.items()),
                f"homed={int(self.homed)}", f"triggers={self.triggers}"]

    def _garbage(self, seq: int) -> list[bytes]:
        """Junk lines a noisy line might carry: each kind must be rejected by the host."""
        out = []
        for i in range(self.garbage_before_reply):
            kind = i % 4
            if kind == 0:  # random bytes, non-ASCII included (no newline inside)
                out.append(b"\xff" + bytes(self._rng.choice([*range(1, 10), *range(11, 256)])
                                            for _ in range(self._rng.randint(1, 40))) + b"\n")
            elif kind == 1:  # a forged OK for the awaited seq with a wrong checksum
                good = encode_frame(seq, "OK").rstrip(b"\n")
                bad = int(good[-2:], 16) ^ 0x5A
                out.append(good[:-2] + f"{bad:02X}\n".encode())
            elif kind == 2:  # no checksum at all
                out.append(f"{seq} OK\n".encode())
            else:  # a valid reply to another request (stale)
                out.append(encode_frame(seq % 9999 + 1, "OK", "stale"))
        return out

    def _take_disconnect(self) -> bool:
        """Whether the connection should be closed now (at most once)."""
        with self._lock:
            if self._disconnect_pending:
                self._disconnect_pending = False
                self._disconnected = True
                return True
            return False

    # -- transports ---------------------------------------------------------------------------

    def serve_fd(self, fd: int) -> threading.Thread:
        """Serve on a file descriptor (a pty master) in a daemon thread; the caller keeps owning
        (and closes) ``fd``, after :meth:`stop`."""
        self._stop.clear()
        t = threading.Thread(target=self._serve_fd, args=(fd,), name="fake-controller-fd", daemon=True)
        self._threads.append(t)
        t.start()
        return t

    def _serve_fd(self, fd: int) -> None:
        buf = bytearray()
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([fd], [], [], _POLL_S)
                chunk = os.read(fd, 4096) if ready else b""
            except OSError as exc:
                if exc.errno == errno.EIO:  # no slave open right now: wait for the host
                    time.sleep(_POLL_S)
                    continue
                return  # fd closed under us
            except ValueError:
                return
            buf += chunk
            for line in _lines(buf):
                out = b"".join(self.handle_line(line))
                self._take_disconnect()  # a pty cannot be disconnected; just clear the flag
                try:
                    _write_all(fd, out)
                except OSError:
                    pass  # the host went away; its retry will ask again

    def serve_tcp(self, host: str = "127.0.0.1", port: int = 0) -> tuple[int, threading.Thread]:
        """Listen on ``host:port`` (0: any free port) and serve connections one after another
        (a host can reconnect after a disconnect) in a daemon thread. Returns the bound port."""
        self._stop.clear()
        srv = socket.create_server((host, port))
        srv.settimeout(_POLL_S)
        t = threading.Thread(target=self._serve_tcp, args=(srv,), name="fake-controller-tcp", daemon=True)
        self._threads.append(t)
        t.start()
        return srv.getsockname()[1], t

    def _serve_tcp(self, srv: socket.socket) -> None:
        with srv:
            while not self._stop.is_set():
                try:
                    conn, _ = srv.accept()
                except TimeoutError:
                    continue
                except OSError:
                    return
                with conn:
                    self._serve_connection(conn)

    def _serve_connection(self, conn: socket.socket) -> None:
        conn.settimeout(_POLL_S)
        buf = bytearray()
        while not self._stop.is_set():
            try:
                chunk = conn.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                return
            if not chunk:
                return  # the host closed the connection
            buf += chunk
            for line in _lines(buf):
                out = b"".join(self.handle_line(line))
                if self._take_disconnect():
                    return  # drop the link with the reply unsent
                try:
                    conn.sendall(out)
                except OSError:
                    return

    def stop(self) -> None:
        """Stop serving: close the listening socket and any connection, end the threads."""
        self._stop.set()
        for t in self._threads:
            t.join(timeout=2.0)
        self._threads = [t for t in self._threads if t.is_alive()]


def _arity_ok(handler: Callable[..., list[str]], args: tuple[str, ...]) -> bool:
    return handler.__code__.co_argcount - 1 == len(args)  # minus self


def _bad_args(name: str, args: tuple[str, ...]) -> list[str]:
    raise _CommandFailed("BADARG", f"{name} does not take {len(args)} argument{'s' if len(args) != 1 else ''}")


def _number(name: str, text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise _CommandFailed("BADARG", f"{name}: {text} is not a number") from None
    if not math.isfinite(v):
        raise _CommandFailed("BADARG", f"{name}: {text} is not finite")
    return v


def _lines(buf: bytearray) -> list[bytes]:
    """Complete lines taken out of ``buf`` (without ``\\n``); a partial line stays in it."""
    out = []
    while (nl := buf.find(b"\n")) >= 0:
        out.append(bytes(buf[:nl]))
        del buf[:nl + 1]
    if len(buf) > 4096:
        buf.clear()  # a line this long is noise; do not grow without bound
    return out


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def main(argv: list[str] | None = None) -> int:
    """Command line: serve a fake bench controller until interrupted."""
    ap = argparse.ArgumentParser(prog="python -m mitsvbrdf.capture.fake_controller",
                                 description="A fake capture-bench controller (mitsvbrdf serial protocol).")
    where = ap.add_mutually_exclusive_group(required=True)
    where.add_argument("--tcp", type=int, metavar="PORT", help="listen on this TCP port (0: any free port)")
    where.add_argument("--pty", action="store_true", help="serve on a new pseudo-terminal (POSIX)")
    ap.add_argument("--host", default="127.0.0.1", help="address to listen on with --tcp")
    ap.add_argument("--garbage", type=int, default=0, metavar="N", help="junk lines before each reply")
    ap.add_argument("--delay", type=float, default=0.0, metavar="S", help="extra seconds per command")
    ap.add_argument("--drop", type=int, action="append", default=[], metavar="SEQ",
                    help="drop the first reply to this seq (repeatable)")
    ap.add_argument("--disconnect-after", type=int, metavar="N", help="drop the TCP link once after N commands")
    ap.add_argument("--fail", action="append", default=[], metavar="CMD=CODE[:MESSAGE]",
                    help="make a command fail, e.g. TRIGGER=FAULT:shutter jammed (repeatable)")
    args = ap.parse_args(argv)
    fail = {}
    for spec in args.fail:
        cmd, sep, err = spec.partition("=")
        if not sep or not cmd:
            ap.error(f"--fail wants CMD=CODE[:MESSAGE], got {spec!r}")
        code, _, message = err.partition(":")
        fail[cmd.upper()] = f"{code or 'FAULT'} {message}".strip()
    dev = FakeControllerDevice(garbage_before_reply=args.garbage, drop_replies=set(args.drop),
                               disconnect_after=args.disconnect_after, delay=args.delay, fail_commands=fail)
    fds: list[int] = []
    if args.pty:
        master, slave = os.openpty()
        fds += [master, slave]  # keep the slave open so the master never sees EIO between hosts
        dev.serve_fd(master)
        url = os.ttyname(slave)
    else:
        port, _ = dev.serve_tcp(args.host, args.tcp)
        url = f"socket://{args.host}:{port}"
    print(url, flush=True)
    done = threading.Event()
    for sig in (signal.SIGINT, getattr(signal, "SIGTERM", None)):
        if sig is not None:  # also when started in the background, where SIGINT is ignored
            signal.signal(sig, lambda *_: done.set())
    try:
        while not done.wait(0.5):
            pass
    finally:
        dev.stop()
        for fd in fds:
            os.close(fd)
    return 0


if __name__ == "__main__":
    sys.exit(main())
