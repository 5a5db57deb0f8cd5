"""A solver call in a forked worker process whose CPU time per call is bounded.

``Guarded`` runs each call in a worker forked from the process. A call that has used more than
``cpu_s`` seconds of CPU, read every ``poll_s`` of wall time, is ended (SIGKILL) and reports
failure, and the next call forks a new worker. Without ``/proc`` the worker's own CPU limit ends
it instead; where the platform cannot fork, calls run in the process, unguarded. Why, and why CPU
time: docs/modules.md.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import select
import signal
import struct
import weakref
from collections.abc import Callable
from typing import Any

from cape.errors import CapeError

_HEADER = struct.Struct("<Q")
_TICKS = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def _send(fd: int, payload: Any) -> None:
    data = pickle.dumps(payload, protocol=pickle.HIGHEST_PROTOCOL)
    view = memoryview(_HEADER.pack(len(data)) + data)
    while view:
        view = view[os.write(fd, view) :]


def _receive(fd: int) -> Any | None:
    """The next message, or None when the other end has gone."""
    header = _read_exactly(fd, _HEADER.size)
    if header is None:
        return None
    body = _read_exactly(fd, _HEADER.unpack(header)[0])
    return None if body is None else pickle.loads(body)


def _read_exactly(fd: int, size: int) -> bytes | None:
    chunks, left = [], size
    while left:
        chunk = os.read(fd, min(left, 1 << 16))
        if not chunk:
            return None
        chunks.append(chunk)
        left -= len(chunk)
    return b"".join(chunks)


class WorkerError(CapeError):
    """A guarded call failed in its worker for a reason of its own (an exception, ``cause``),
    not by its CPU limit."""

    def __init__(self, cause: str, cpu_s: float) -> None:
        self.cause = cause
        super().__init__(
            f"a guarded solver call failed in its worker ({cause}), which is not its CPU limit "
            f"of {cpu_s} s; check the controller's settings, else report it"
        )


class Guarded:
    """``guarded(request) → handler(request)``, or None when the call used more than
    ``cpu_s`` seconds of CPU (or its worker died otherwise)."""

    def __init__(self, handler: Callable[[Any], Any], cpu_s: float, poll_s: float = 0.02) -> None:
        self.handler = handler
        self.cpu_s = float(cpu_s)
        self.poll_s = poll_s
        self.pid: int | None = None
        self.limited = 0  # calls ended by the limit
        self.errors = 0  # calls that failed in the worker for a reason of their own
        self._to: int | None = None
        self._from: int | None = None

    def __call__(self, request: Any) -> Any | None:
        if not hasattr(os, "fork"):
            return self.handler(request)
        if self.pid is None:
            self._start()
        assert self._to is not None and self._from is not None
        try:
            before = self._worker_cpu()
            _send(self._to, request)
            reply = self._await(before)
        except (BrokenPipeError, ConnectionResetError):
            reply = None
        if reply is None:
            self.limited += 1
            self.close()
            return None
        status, value = reply
        if status == "error":  # the worker's own failure: not a limit, and never silent
            self.close()
            self.errors += 1
            raise WorkerError(value, self.cpu_s)
        return value

    def _await(self, before: float | None) -> Any | None:
        """The worker's reply, or None once it has used ``cpu_s`` of CPU on this call."""
        assert self._from is not None
        while not select.select([self._from], [], [], self.poll_s)[0]:
            now = self._worker_cpu()
            if before is not None and now is not None and now - before > self.cpu_s:
                return None
        return _receive(self._from)

    def _worker_cpu(self) -> float | None:
        """The worker's user + system CPU seconds so far (None where /proc cannot tell)."""
        try:
            with open(f"/proc/{self.pid}/stat", "rb") as f:
                fields = f.read().rsplit(b")", 1)[1].split()
        except OSError:
            return None
        return (int(fields[11]) + int(fields[12])) / _TICKS

    def _start(self) -> None:
        request_r, request_w = os.pipe()
        reply_r, reply_w = os.pipe()
        pid = os.fork()
        if pid == 0:  # the worker: never returns into the caller's code
            code = 1
            try:
                os.close(request_w)
                os.close(reply_r)
                self._serve(request_r, reply_w)
                code = 0
            finally:
                os._exit(code)
        os.close(request_r)
        os.close(reply_w)
        self.pid, self._to, self._from = pid, request_w, reply_r
        # a worker ends with its owner, also in a long-lived process that builds many of them
        self._finalizer = weakref.finalize(self, _stop, pid, request_w, reply_r)

    def _serve(self, requests: int, replies: int) -> None:
        import resource  # POSIX only, like fork

        signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent is the one to interrupt
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))  # SIGXCPU would dump core
        hard = resource.getrlimit(resource.RLIMIT_CPU)[1]
        while (request := _receive(requests)) is not None:
            try:
                used = resource.getrusage(resource.RUSAGE_SELF)
                soft = int(used.ru_utime + used.ru_stime) + 2 + int(self.cpu_s)
                if hard != resource.RLIM_INFINITY:
                    soft = min(soft, hard)
                resource.setrlimit(resource.RLIMIT_CPU, (soft, hard))
                reply = ("ok", self.handler(request))
            except Exception as exc:  # told to the caller, which raises it (WorkerError)
                reply = ("error", f"{type(exc).__name__}: {exc}")
            _send(replies, reply)

    def close(self) -> None:
        """End the worker (it also ends when this object is collected or the process exits)."""
        if self.pid is not None:
            self._finalizer()
        self.pid = self._to = self._from = None


def _stop(pid: int, to: int, back: int) -> None:
    for fd in (to, back):
        with contextlib.suppress(OSError):
            os.close(fd)
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGKILL)
    with contextlib.suppress(ChildProcessError):
        os.waitpid(pid, 0)
