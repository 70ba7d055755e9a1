"""Whether a process that left a mark on disk (a pass claim, a temporary directory's owner file) still
runs on this host: it exists, it is not a zombie (killed, not yet reaped), and — where its start time was
recorded — it is the same process, not an unrelated one that reuses its PID. Linux ``/proc`` gives the
state and start time; elsewhere only existence is checked."""

from __future__ import annotations

import os

__all__ = ["process_alive", "process_start"]


def _stat_fields(pid: int) -> list[str]:
    """The fields of ``/proc/<pid>/stat`` after the command name (state first), or [] where unreadable."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            stat = f.read()
    except OSError:
        return []
    return stat.rsplit(")", 1)[-1].split()  # the name may hold spaces and parentheses: split after the last


def process_start(pid: int) -> str | None:
    """The start time of ``pid`` (clock ticks since boot, Linux ``/proc``), or None where unknown."""
    fields = _stat_fields(pid)
    return fields[19] if len(fields) > 19 else None


def process_alive(pid: int, start: str | None = None) -> bool:
    """True when process ``pid`` runs on this host (also one owned by another user) and is not a zombie;
    with ``start`` (its `process_start` when the mark was made), also when its start time is still that one
    (where either is unknown, the PID alone decides)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # exists, owned by another user
    fields = _stat_fields(pid)
    if fields and fields[0] == "Z":
        return False  # killed, not yet reaped
    now = fields[19] if len(fields) > 19 else None
    return start is None or now is None or start == now
