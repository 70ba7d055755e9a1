"""User code contained: a user approximation is loaded and validated in a child process first, under a
time limit, and only then loaded into rtfit's own process (issue 32).

``--approx my.py:f`` and entry points run **the user's Python code with the user's rights** (rtfit cannot
sandbox what that code may do to files or the network). What rtfit does contain is how that code can end
the run: before the audit loads a user approximation it runs `load_approximation` and
`check_approximation` (`rtfit.experiments.user_methods`) in a child Python process, and reads the outcome
over a pipe of its own. Whatever the user's code does there is one `UserMethodError` line naming the
function (exit status 2 from the command line), never rtfit's own exit:

* ``sys.exit(n)`` at import or in the function: a one-line error (never exit status ``n``, never 0);
* ``os._exit(n)``, a crash (a signal) or anything else that ends the child without an answer: "the
  process ended … while loading/checking" (the last phase the child reported);
* ``raise KeyboardInterrupt`` in user code: a one-line error (never exit status 130: the child ignores
  SIGINT, so a KeyboardInterrupt there can only come from the user's code; Ctrl-C reaches rtfit's own
  process, which stops the child and is interrupted as usual);
* an endless loop: the child is killed after `timeout_s` seconds of user code
  (``$RTFIT_APPROX_TIMEOUT_S``, default `DEFAULT_TIMEOUT_S`; the clock starts once the child has imported
  rtfit, so a slow start-up on a loaded machine is not counted);
* a warning raised by user code: one ``rtfit: warning:`` line each (logger ``rtfit.audit``), once.

Once the child answered "valid", the approximation is loaded in-process (its warnings not repeated) and
returned; its validation is not run a second time.

The child is this module run as ``python -m rtfit.experiments.user_sandbox FD SPEC`` with the parent's
``sys.path`` in ``$RTFIT_SANDBOX_PATH`` (so ``module:name`` specs and entry points are found as in the
parent); it writes JSON lines to file descriptor ``FD``.
"""

from __future__ import annotations

import json
import logging
import math
import os
import select
import signal
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

from rtfit.realtime.methods import Method

from .user_methods import UserMethodError, check_approximation, load_approximation

__all__ = ["DEFAULT_TIMEOUT_S", "TIMEOUT_ENV", "load_validated", "timeout_s"]

TIMEOUT_ENV = "RTFIT_APPROX_TIMEOUT_S"
DEFAULT_TIMEOUT_S = 30.0
"""Seconds of user code (loading and validating one approximation) before the child is killed. Validation
evaluates the function on 256 samples at ≤ 1 + 2·(parameters) parameter sets on NumPy and Dr.Jit: well
under a second of work plus Dr.Jit's kernel compilation (a few seconds on a loaded 2-core machine)."""
TIMEOUT_MAX_S = 86400.0  # a day: beyond it a limit is no limit (and time.monotonic arithmetic stays exact)
STARTUP_LIMIT_S = 300.0  # the child's own import of rtfit, NumPy and Dr.Jit, not the user's code
_PATH_ENV = "RTFIT_SANDBOX_PATH"
_USER = "the user's code"

log = logging.getLogger("rtfit.audit")


def timeout_s() -> float:
    """The time limit for user code (``$RTFIT_APPROX_TIMEOUT_S``, seconds, in (0, `TIMEOUT_MAX_S`]; default
    `DEFAULT_TIMEOUT_S`). A value that is not such a number is a one-line `UserMethodError`."""
    text = os.environ.get(TIMEOUT_ENV, "").strip()
    if not text:
        return DEFAULT_TIMEOUT_S
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and 0.0 < value <= TIMEOUT_MAX_S):
        raise UserMethodError(
            f"${TIMEOUT_ENV}={text[:40]!r}: expected seconds in (0, {TIMEOUT_MAX_S:g}] "
            f"(the time limit for loading and validating an approximation; default {DEFAULT_TIMEOUT_S:g})"
        )
    return value


def _signal_name(rc: int) -> str:
    try:
        return signal.Signals(-rc).name
    except ValueError:
        return f"signal {-rc}"


def _ended(spec: str, phase: str, rc: int) -> UserMethodError:
    how = f"was killed by {_signal_name(rc)}" if rc < 0 else f"exited with status {rc}"
    return UserMethodError(
        f"{spec}: the Python process {how} while {phase} it, without an answer (os._exit or a crash in "
        f"{_USER}? an approximation must return values or raise an exception)"
    )


class _Child:
    """The child process and the JSON lines it wrote so far."""

    def __init__(self, spec: str):
        read, write = os.pipe()
        self.fd = read
        self.buffer = b""
        self.err = tempfile.TemporaryFile()
        env = {**os.environ, _PATH_ENV: json.dumps(sys.path)}
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", __name__, str(write), spec],
                pass_fds=(write,),
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,  # the user's prints: not rtfit's output
                stderr=self.err,
                env=env,
            )
        finally:
            os.close(write)

    def messages(self, deadline: float) -> list[dict] | None:
        """The messages that arrive before ``deadline`` (monotonic); None at end of file."""
        wait = max(0.0, deadline - time.monotonic())
        ready, _, _ = select.select([self.fd], [], [], min(wait, 0.5))
        if not ready:
            return []
        chunk = os.read(self.fd, 1 << 16)
        if not chunk:
            return None
        self.buffer += chunk
        *lines, self.buffer = self.buffer.split(b"\n")
        out = []
        for line in lines:
            try:
                msg = json.loads(line)
            except (UnicodeDecodeError, json.JSONDecodeError):
                continue  # something the user's code wrote to our pipe: not ours
            if isinstance(msg, dict):
                out.append(msg)
        return out

    def close(self, wait_s: float = 0.0) -> int:
        """Stop the child (after ``wait_s`` seconds to end by itself) and return its exit status."""
        try:
            self.proc.wait(timeout=wait_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        rc = self.proc.wait()
        os.close(self.fd)
        self.err.close()
        return rc


def _follow(child: _Child, spec: str, limit: float) -> str | None:
    """Read the child's messages until its answer (None: valid; a failure raises `UserMethodError`) or
    its end without one (the phase it was in)."""
    phase, ready = "starting Python for", False
    deadline = time.monotonic() + STARTUP_LIMIT_S
    while True:
        if time.monotonic() > deadline:
            if not ready:
                raise UserMethodError(
                    f"{spec}: the validation process did not start within {STARTUP_LIMIT_S:g} s"
                )
            raise UserMethodError(
                f"{spec}: {phase} it did not finish within {limit:g} s (an endless loop in {_USER}? "
                f"${TIMEOUT_ENV} sets the limit)"
            )
        msgs = child.messages(deadline)
        if msgs is None:
            return phase
        for msg in msgs:
            if "phase" in msg:
                phase = str(msg["phase"])
                if not ready:
                    ready, deadline = True, time.monotonic() + limit
            elif "warning" in msg:
                log.warning("%s", " ".join(str(msg["warning"]).split()))
            elif "error" in msg:
                raise UserMethodError(" ".join(str(msg["error"]).split()), stage=str(msg.get("stage", "")))
            elif msg.get("ok"):
                return None


def _validate_in_child(spec: str, limit: float) -> None:
    """Run load + check of ``spec`` in a child process (module docstring); None when it passes. Ctrl-C in
    rtfit's own process stops the child and interrupts as usual."""
    child = _Child(spec)
    phase: str | None = None
    try:
        phase = _follow(child, spec, limit)
    finally:  # an answer or a refusal: the child is done, stop it; an end of file: let it end (its status)
        rc = child.close(wait_s=5.0 if phase is not None else 0.0)
    if phase is not None:
        raise _ended(spec, phase, rc)


def load_validated(spec: str, *, timeout: float | None = None) -> Method:
    """The user approximation ``spec`` (``file.py:name``, ``module:name`` or an entry point), loaded and
    validated in a child process under a time limit (``timeout`` seconds of user code, default
    `timeout_s()`), then loaded in-process. Every failure is one `UserMethodError` line naming the spec or
    the function (module docstring)."""
    limit = timeout_s() if timeout is None else timeout
    _validate_in_child(spec, limit)
    with warnings.catch_warnings():  # reported once already, by the child
        warnings.simplefilter("ignore")
        return load_approximation(spec)


# ------------------------------------------------------------------------------------------------ child
_LIBRARY_NOISE = (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning)


def _from_user(w: warnings.WarningMessage, spec: str) -> bool:
    """Whether the warning is attributed to the spec's own file (``file.py:name``)."""
    module = spec.rpartition(":")[0]
    return bool(module) and Path(str(w.filename)).name == Path(module).name


def _warning_line(spec: str, w: warnings.WarningMessage) -> str:
    where = f"{Path(str(w.filename)).name} line {w.lineno}"
    return f"{spec}: {where}: {w.category.__name__}: {w.message}"


def _child_main(fd: int, spec: str) -> int:
    """The child's side: report ``ready``, load and check ``spec``, report the outcome; never raises."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    with os.fdopen(fd, "w", buffering=1, encoding="utf-8", closefd=True) as pipe:

        def send(**msg) -> None:
            pipe.write(json.dumps(msg) + "\n")
            pipe.flush()

        paths = os.environ.get(_PATH_ENV)
        if paths:
            sys.path[:] = json.loads(paths)
        import drjit  # noqa: F401  (drjit: its start-up is not the user's time)

        phase = "loading"
        name = spec
        seen: set[str] = set()
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                send(phase=phase)
                method = load_approximation(spec)
                phase, name = "checking", f"{method.id} ({spec})" if method.id not in spec else spec
                send(phase=phase)
                check_approximation(method)
            for w in caught:
                if issubclass(w.category, _LIBRARY_NOISE) and not _from_user(w, spec):
                    continue
                line = _warning_line(spec, w)
                if line not in seen:
                    seen.add(line)
                    send(warning=line)
            send(ok=True)
        except UserMethodError as e:
            send(error=str(e), stage=e.stage or phase)
        except SystemExit as e:
            send(error=f"{name}: {_USER} called sys.exit({e.code!r}) while {phase} it")
        except KeyboardInterrupt:
            send(error=f"{name}: {_USER} raised KeyboardInterrupt while {phase} it")
        except BaseException as e:  # anything else user code may raise
            text = " ".join(str(e).split())
            send(error=f"{name}: {type(e).__name__} while {phase} it" + (f": {text}" if text else ""))
    return 0


if __name__ == "__main__":
    os._exit(_child_main(int(sys.argv[1]), sys.argv[2]))
