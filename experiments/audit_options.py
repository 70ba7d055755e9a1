"""The audit's option checks (`audit_run.audit`, ``rtfit audit``): each bad value one line (`AuditError`)
before anything is read or rendered."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from rtfit.scenes.parse import MAX_LENGTH

from .atomic import writable_problem
from .audit import AuditError
from .registry import LIMITS

__all__ = ["GRID_MAX", "check_ao_distance", "check_out", "check_sizes", "triple"]


def check_out(out: Path, option: str = "--out") -> None:
    """``out`` a directory this process can create and write (`writable_problem`), or a one-line error."""
    problem = writable_problem(out)
    if problem is not None:
        raise AuditError(f"{option} {out}: {problem}")


def check_ao_distance(value) -> None:
    """``--ao-distance``: None (the default from the scene's size), or a finite distance in (0, 1e8] scene
    units (`rtfit.scenes.parse.MAX_LENGTH`, the TOML scenes' limit). nan, inf and 1e30 were accepted, and
    the AO family then said "give --ao-distance" although it was given (issue 32)."""
    if value is None:
        return
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 < value <= MAX_LENGTH:
        raise AuditError(
            f"--ao-distance {value!r}: must be a finite distance in (0, {MAX_LENGTH:g}] scene units"
        )


def check_sizes(spp: int, pass_spp: int, width, height) -> None:
    """spp, pass-spp, passes and film sizes within the shared limit table (`registry.LIMITS`)."""
    try:
        LIMITS["spp"].check("--spp", spp)
        LIMITS["spp"].check("--pass-spp", pass_spp)
        LIMITS["passes"].check(f"--spp {spp} / --pass-spp {pass_spp} =", -(-spp // pass_spp))
        for option, value in (("--width", width), ("--height", height)):
            if value is not None:
                LIMITS["resolution"].check(option, value)
    except ValueError as e:
        raise AuditError(str(e)) from None


GRID_MAX = 64
"""Most probes along one axis of ``--grid``."""


def triple(option: str, value, kind) -> Any:
    """``value`` (None, ``"a,b,c"`` or three numbers) as a tuple of three ``kind`` (float: finite; int: 1 …
    `GRID_MAX`), or `AuditError` (one line, before anything runs)."""
    if value is None:
        return None
    parts = value.split(",") if isinstance(value, str) else list(value)
    what = "three finite numbers X,Y,Z" if kind is float else f"three integers NX,NY,NZ in 1…{GRID_MAX}"
    if len(parts) != 3:
        raise AuditError(f"{option} {value!r}: expected {what}")
    try:
        out = tuple(float(str(p).strip()) for p in parts)
    except ValueError:
        raise AuditError(f"{option} {value!r}: expected {what}") from None
    if kind is float:
        if not all(math.isfinite(v) for v in out):
            raise AuditError(f"{option} {value!r}: expected {what}")
        return out
    if not all(v.is_integer() and 1 <= v <= GRID_MAX for v in out):
        raise AuditError(f"{option} {value!r}: expected {what}")
    return tuple(int(v) for v in out)
