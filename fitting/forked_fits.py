"""Fits (and other NumPy work) shared between this process and one forked helper: `shared_map` (issue 33).
The audit's fits (`rtfit.experiments.audit_cases.CaseRun.fit_cases`), then its metrics, a case a task
(`CaseRun.finish_cases`, session 30), and its report's figures
(`rtfit.experiments.audit_output.case_figures`).

A fit of the audit runs on one core: SciPy's TRF on the NumPy run of a kernel text (`fit_method`
``solver="trf"``), one BLAS thread, each kernel evaluation a few NumPy passes over a few thousand elements
that hold the GIL for most of their time (threads were measured slower: session 28). On a machine of two
cores the other one idles through the fits, which were 2.6–3.8 s of a 64² × 32 spp audit of Mitsuba's
Cornell box against its references' 1.1–1.6 s. `shared_map` runs a list of such tasks on two processes: this
one and a child made by ``fork``, which inherits every case's arrays, the kernels' closures and the imported
modules as they are (nothing is pickled on the way in: a `Method`'s kernel is often a closure over a case's
tables, which no pickle carries), and sends back each result, pickled.

The rules that keep the results those of a serial run, bit for bit:

- A task runs the same code on the same data in either process: NumPy and SciPy give the same bits (one BLAS
  thread in both: `one_blas_thread`).
- Only tasks the caller marks ``child_may`` run in the child. A fork copies no thread: a fit on Dr.Jit
  (`Method.fit_ops` ``"drjit"``) may run there only where the parent's Dr.Jit pool had no worker thread at
  the fork (its kernels would otherwise wait for workers the child does not have) and its backend is LLVM
  (a CUDA context does not survive a fork): on two cores `rtfit.experiments.audit_cases` shrinks the pool
  to the calling thread while the helper runs (session 34), and the child then runs each kernel on its own
  thread.
- A task the child does not finish (an exception, a crash, no answer in time) is run again here, where it
  raises what a serial run would; the child is then stopped.

Bounds: the child's silence is bounded (`_child_quiet_limit`): where no result comes for that long after
this process ran out of tasks, the child is killed and its tasks run here. The child exits with ``os._exit``
(no interpreter clean-up: the parent's objects, Dr.Jit's among them, are not finalised twice) and with its
cycle collector off (nothing the parent owns is finalised in the child).
"""

from __future__ import annotations

import gc
import mmap
import os
import pickle
import select
import shutil
import signal
import struct
import sys
import tempfile
import time
import warnings
from collections.abc import Callable, Sequence
from typing import Any

__all__ = ["limit_cores", "shared_map", "shares", "two_cores"]

_FREE, _PARENT, _CHILD = 0, 1, 2
_HEADER = struct.Struct("<iQ?")  # task index (−1: the child has no task left), pickled length, in a file?
_PIPE_PAYLOAD = 32 << 10
"""The largest result (pickled bytes) the child writes into the pipe; a larger one goes into a file of the
parent's spill directory, and the pipe carries its header only. A pipe holds 64 KiB: a result larger than
that left the child blocked in its write until the parent, busy with a task of its own, read the pipe again
(issue 33, session 30: a case's metrics with its ꟻLIP maps, ~200 KB at 64², kept the helper waiting 0.28 s
of a 0.44 s phase)."""


_CORE_BUDGET: list[int | None] = [None]


def limit_cores(cores: int | None) -> None:
    """This process's share of the machine's cores (None: all it may run on): a job worker of a process pool
    given one core (`rtfit.experiments.jobs`) forks no helper, whose work would only take its neighbour's."""
    _CORE_BUDGET[0] = cores


def two_cores() -> bool:
    """Whether this process may run on two cores or more (`limit_cores`) and can ``fork`` safely: Linux only
    (macOS's system frameworks do not support a fork without an exec)."""
    if not (sys.platform.startswith("linux") and hasattr(os, "fork")):
        return False
    if _CORE_BUDGET[0] is not None and _CORE_BUDGET[0] < 2:
        return False
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    return cores >= 2


def _child_quiet_limit(longest: float) -> float:
    """Seconds this process waits for the child's next result once it has no task of its own left: 10 s, or
    8 × the longest task either process finished where that is more (the tasks are fits of one audit, of
    comparable size; a child that is that late is stuck, not slow)."""
    return max(10.0, 8.0 * longest)


class _Claims:
    """Which process runs each task: one byte per task in memory shared by both processes (0 free,
    1 here, 2 the child), taken under one lock (a pipe holding one token: no thread, no semaphore file)."""

    def __init__(self, n: int):
        self.bytes = mmap.mmap(-1, max(n, 1))
        self.token_r, self.token_w = os.pipe()
        os.write(self.token_w, b"x")

    def take(self, order: Sequence[int], who: int, gone: Callable[[], bool] | None = None) -> int | None:
        """The first free task of ``order`` marked as ``who``'s, or None where none is free. ``gone``: whether
        the other process has died (the parent's check, every 0.5 s of waiting for the token: a child killed
        while it held the token never gives it back, and the parent then takes the lock itself)."""
        while gone is not None and not select.select([self.token_r], [], [], 0.5)[0]:
            if gone():
                break
        else:
            os.read(self.token_r, 1)  # the lock: one token in the pipe
        try:
            for i in order:
                if self.bytes[i] == _FREE:
                    self.bytes[i] = who
                    return i
            return None
        finally:
            os.write(self.token_w, b"x")

    def close(self) -> None:
        self.bytes.close()
        for fd in (self.token_r, self.token_w):
            os.close(fd)


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


def _send(fd: int, index: int, payload: bytes, spill: str | None = None) -> None:
    """One message: its header, then the payload in the pipe, or (a payload over `_PIPE_PAYLOAD`, with a
    spill directory) in the file ``spill/<index>`` (written whole before its header is sent)."""
    if spill is not None and len(payload) > _PIPE_PAYLOAD:
        with open(os.path.join(spill, str(index)), "wb") as f:
            f.write(payload)
        _write_all(fd, _HEADER.pack(index, len(payload), True))
        return
    _write_all(fd, _HEADER.pack(index, len(payload), False) + payload)


def _child(
    tasks: Sequence[Any], run: Callable[[Any], Any], claims: _Claims, order: list[int], fd: int, spill: str
):
    """The child's loop: take the last free task it may run, run it, send (index, pickled ("ok", result,
    seconds) or ("error", None, 0)); at the end a header of index −1. Never returns."""
    try:
        gc.disable()  # nothing of the parent's is finalised here
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle: it kills this child
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # (not the parent's handler: a SIGTERM ends the child)
        while True:
            i = claims.take(order, _CHILD)
            if i is None:
                break
            t = time.perf_counter()
            try:
                out = ("ok", run(tasks[i]), time.perf_counter() - t)
                payload = pickle.dumps(out, protocol=pickle.HIGHEST_PROTOCOL)
            except BaseException:  # the parent runs the task again and raises what it raises
                payload = pickle.dumps(("error", None, 0.0))
            _send(fd, i, payload, spill)
        _send(fd, -1, b"")
    finally:
        os._exit(0)


class _Reader:
    """The parent's end of the result pipe: complete messages parsed as they arrive (a payload the child
    spilled read from its file, `_send`)."""

    def __init__(self, fd: int, spill: str):
        self.fd, self.buf, self.done, self.spill = fd, b"", False, spill
        self.heard = False
        """Whether the latest `poll` read any bytes (a message may come in several reads)."""

    def poll(self, timeout: float | None) -> list[tuple[int, Any]]:
        """The messages complete after waiting at most ``timeout`` s for data (0: none waited for)."""
        out: list[tuple[int, Any]] = []
        self.heard = False
        if self.done:
            return out
        ready, _, _ = select.select([self.fd], [], [], timeout)
        while ready:
            self.heard = True
            chunk = os.read(self.fd, 1 << 16)
            if not chunk:  # the child exited (or died) without its final header
                self.done = True
                break
            self.buf += chunk
            ready, _, _ = select.select([self.fd], [], [], 0)
        while len(self.buf) >= _HEADER.size:
            index, size, spilled = _HEADER.unpack_from(self.buf)
            inline = 0 if spilled else size
            if len(self.buf) < _HEADER.size + inline:
                break
            payload = self.buf[_HEADER.size : _HEADER.size + inline]
            self.buf = self.buf[_HEADER.size + inline :]
            if index < 0:
                self.done = True
                break
            if spilled:
                path = os.path.join(self.spill, str(index))
                with open(path, "rb") as f:
                    payload = f.read()
                os.unlink(path)
            out.append((index, pickle.loads(payload)))
        return out


def shares(child_may: Sequence[bool]) -> bool:
    """Whether `shared_map` forks a helper for tasks the child may run where ``child_may`` says: at least two
    of them, and two cores (`two_cores`)."""
    return sum(map(bool, child_may)) >= 2 and two_cores()


def shared_map(
    tasks: Sequence[Any],
    run: Callable[[Any], Any],
    child_may: Sequence[bool],
    before: Callable[[], Any] | None = None,
) -> tuple[list[Any], list[float]]:
    """``[run(t) for t in tasks]`` and each task's seconds, the tasks shared between this process and one
    forked child where there are at least two the child may run (``child_may``) and two cores
    (`two_cores`); otherwise in turn here. This process takes the tasks from the front (those the child may
    not run first), the child from the back. ``run``'s results must pickle; an exception is raised here, by
    running the task here. ``before``: work of this process's own that it does first, after the fork (the
    child is at the tasks meanwhile), or before the tasks where nothing is shared; the child never runs it
    and does not see what it did (an import there is this process's alone)."""
    n = len(tasks)
    seconds = [0.0] * n

    def timed(i: int) -> Any:
        t = time.perf_counter()
        out = run(tasks[i])
        seconds[i] = time.perf_counter() - t
        return out

    if not shares(child_may):
        if before is not None:
            before()
        return [timed(i) for i in range(n)], seconds
    shareable = [i for i in range(n) if child_may[i]]
    mine = [i for i in range(n) if not child_may[i]] + shareable
    theirs = shareable[::-1]
    claims = _Claims(n)
    spill = tempfile.mkdtemp(prefix="rtfit-shared-")  # (large results: `_PIPE_PAYLOAD`)
    r, w = os.pipe()
    with warnings.catch_warnings():
        # Python ≥ 3.12 warns of a fork in a process with threads, and JAX (where a caller's process has used
        # it) of a fork after its backends started: the child runs neither threads nor JAX (module text).
        warnings.simplefilter("ignore", DeprecationWarning)
        warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called", category=RuntimeWarning)
        pid = os.fork()
    if pid == 0:  # pragma: no cover  (the child: measured by the parent's results)
        os.close(r)
        _child(tasks, run, claims, theirs, w, spill)
    os.close(w)
    reader = _Reader(r, spill)
    results: dict[int, Any] = {}
    failed: set[int] = set()

    def collect(messages):
        for i, (status, value, took) in messages:
            if status == "ok":
                results[i], seconds[i] = value, took
            else:
                failed.add(i)

    try:
        if before is not None:
            before()
        while (i := claims.take(mine, _PARENT, gone=lambda: _exited(pid))) is not None:
            results[i] = timed(i)
            collect(reader.poll(0))
        while not reader.done:
            if all(claims.bytes[i] != _CHILD or i in results or i in failed for i in theirs):
                collect(reader.poll(0))
                break
            collect(reader.poll(_child_quiet_limit(max(seconds))))
            if not reader.heard:  # silent for too long: stuck, not slow
                break
    finally:
        _stop(pid)
        os.close(r)
        claims.close()
        shutil.rmtree(spill, ignore_errors=True)
    return [results[i] if i in results else timed(i) for i in range(n)], seconds


def _exited(pid: int) -> bool:
    """Whether the child ``pid`` has exited (then reaped)."""
    try:
        return os.waitpid(pid, os.WNOHANG)[0] != 0
    except ChildProcessError:
        return True


def _stop(pid: int) -> None:
    """The child killed (where it still runs) and reaped."""
    try:
        done, _ = os.waitpid(pid, os.WNOHANG)
        if done == 0:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
    except ChildProcessError:
        pass
