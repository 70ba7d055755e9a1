"""`rtfit.reference.processes`: a mark's process is alive only while it exists, is not a zombie and (where
recorded) has the start time it had — the pass claims and the temporary directories' owners use one check."""

from __future__ import annotations

import os
import subprocess
import sys
import time

from rtfit.reference.processes import process_alive, process_start


def test_this_process_is_alive_with_its_own_start_time():
    me = os.getpid()
    start = process_start(me)
    assert start is not None and start.isdigit()
    assert process_alive(me)
    assert process_alive(me, start)


def test_a_reused_pid_is_not_the_marked_process():
    # the mark's start time differs from the running process's: an unrelated process reuses the PID
    assert not process_alive(os.getpid(), "0")


def test_no_process_at_pid_zero_or_below():
    assert not process_alive(0)
    assert not process_alive(-5)


def test_a_reaped_child_is_dead():
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    assert not process_alive(child.pid)


def test_a_zombie_is_dead():
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    try:
        deadline = time.monotonic() + 30
        while process_alive(child.pid) and time.monotonic() < deadline:  # exits, not yet reaped: a zombie
            time.sleep(0.05)
        assert os.path.exists(f"/proc/{child.pid}")  # still in the process table
        assert not process_alive(child.pid)
    finally:
        child.wait()
