"""Bounds on every reference pass: a per-lane cap on medium events, and a wall-time budget per pass.

**Medium-event cap.** Delta and ratio tracking loop until a path leaves its medium; Mitsuba's integrator
loop has no bound of its own, so a medium whose majorant is wrong (or a float32 corner case) can keep
one GPU lane busy forever, and with it the whole kernel launch. rtfit's Python media therefore count,
per lane, the free-flight samples they are asked for (`LaneCounter.tick`, one atomic increment in
``intersect_aabb``, which Mitsuba calls once per ``sample_interaction``). A lane past ``MEDIUM_EVENT_CAP``
is absorbed at its next collision (majorant and σt set to `ABSORB`, σs = σn = 0): its path weight
becomes zero and the loop ends for it. The pass then fails: `check` raises `PassBudgetExceeded` with
one line naming the lanes, so a pass that lost lanes is never stored as a reference.

The lane index travels in ``ray.time``: rtfit's passes (`rtfit.reference.estimators.radiance_pass`,
`rtfit.reference.nishita_sky.sky_pass`) set it to the lane's index in the launch (exact in float32:
launches have at most 2^24 lanes). rtfit's scenes are static, and Mitsuba 3 uses a ray's time only for
time-dependent plugins (``timed_sunsky``; none in rtfit's scenes): the time changes no sample.
The count is a tally of ``sample_interaction`` calls, main path and shadow rays together; measured
on the height-fog and sky references: at most a few hundred per lane (docs/height-fog.md), so the
cap (2^16) is never reached by a healthy pass.

**Wall-time budget.** A kernel that never returns cannot be interrupted from the host; the only bound
is the process. `PassWatchdog` arms a timer per pass (``RTFIT_PASS_BUDGET_S``, default
`DEFAULT_PASS_BUDGET_S`); when it expires it writes one line naming the case and the pass to stderr
and ends the process (exit status 1). Passes already rendered stay in the cache, so the rerun
resumes from them.
"""

from __future__ import annotations

import os
import sys
import threading

import drjit as dr
import numpy as np

MEDIUM_EVENT_CAP = 1 << 16
"""Free-flight samples (``sample_interaction`` calls) one lane may take in one launch."""
ABSORB = 1e30
"""Majorant and σt given to an exhausted lane: it collides at once and is absorbed (σs = 0)."""
DEFAULT_PASS_BUDGET_S = 1800.0
"""Wall seconds one pass may take unless ``RTFIT_PASS_BUDGET_S`` says otherwise."""
MAX_TIMED_LANES = 1 << 24
"""Lane indices carried in ``ray.time`` are exact float32 integers below this bound."""


class PassBudgetExceeded(RuntimeError):
    """A pass broke its budget (medium events per lane or wall time); the message is one line."""


class NonFinitePass(RuntimeError):
    """A pass came back with a NaN or infinite mean or variance: it is never stored (a reference must be
    finite everywhere; one bad sample poisons its pixel for every later fit and metric). The message is one
    line naming the case, the pass and the first elements. Found this way: a float32 0/0 in one sample of ~10⁷
    of the sky integrator on CUDA (`rtfit.reference.sky_integrator`, ``BELOW_ONE``)."""


def check_finite(result, what: str):
    """``result`` (a pass: ``mean`` and ``var`` arrays) if both are finite everywhere, else `NonFinitePass`
    whose one line starts with ``what`` (the case and pass, or the bench row). The pass store refuses such a
    pass; the media benches refuse to time one (the H200's first sky bench printed a rate beside a ``nan``
    variance for the NaN sample the full run then hit)."""
    bad = ~(np.isfinite(result.mean) & np.isfinite(result.var))
    if bad.any():
        first = ", ".join(str(int(i)) for i in np.flatnonzero(bad)[:3])
        raise NonFinitePass(
            f"{what}: {int(bad.sum())} non-finite values in the mean or variance (first at flat indices "
            f"{first}): not stored"
        )
    return result


class LaneCounter:
    """Per-lane medium-event counts of one launch (``UInt32`` on the launch's backend).

    A medium holds one (`arm` per launch, `disarm` after). Unarmed, `tick` counts nothing and never
    absorbs: the medium then behaves as plain Mitsuba code (tests calling it directly)."""

    def __init__(self, cap: int = MEDIUM_EVENT_CAP):
        if cap < 1:
            raise ValueError(f"cap must be >= 1 (got {cap})")
        self.cap = int(cap)
        self.counts = None

    def arm(self, uint32_type, lanes: int) -> None:
        if not 0 < lanes <= MAX_TIMED_LANES:
            raise ValueError(f"lanes must be in [1, {MAX_TIMED_LANES}] (got {lanes})")
        self._type, self._lanes = uint32_type, int(lanes)
        self.counts = []

    def disarm(self) -> None:
        self.counts = None

    def tick(self, time):
        """Count one event for the lanes whose index is ``time``; True where a lane is past the cap
        (Python ``False`` when unarmed).

        Each call (in symbolic code: each trace of the medium, i.e. each call site of Mitsuba's
        integrator: the path loop, the shadow-ray loops) counts into its own array: an atomic
        increment reads its target, and Dr.Jit cannot read an array that another symbolic region of
        the same kernel writes. The cap thus bounds each call site's events per lane."""
        if self.counts is None:
            return False
        if not self.counts or dr.flag(dr.JitFlag.SymbolicScope):
            counts = dr.zeros(self._type, self._lanes)
            dr.make_opaque(counts)  # a scatter target must exist in memory before symbolic code runs
            self.counts.append(counts)
        counts = self.counts[-1]
        return dr.scatter_inc(counts, self._type(time)) >= self.cap

    def within(self, time):
        """Count one event for the lanes whose index is ``time`` (`tick`); True where a lane may go on, i.e.
        is not past the cap (Python ``True`` when unarmed: ``mi.render`` and scalar variants). The loop
        guard of rtfit's path-tracing integrators."""
        stop = self.tick(time)
        return ~stop if dr.is_array_v(stop) else True

    def exhausted(self) -> int:
        """How many lanes reached the cap at some call site in the launch (0 when unarmed)."""
        if not self.counts:
            return 0
        hit = dr.zeros(dr.mask_t(self._type), self._lanes)
        for c in self.counts:
            hit |= c > self.cap  # a lane past the cap had an event absorbed
        return _int(dr.count(hit))

    def means(self) -> list[float]:
        """Events per lane of the launch at each call site, in the order they were traced (empty when
        unarmed): the work per sample the benches report."""
        return [_float(dr.mean(c * 1.0)) for c in self.counts or ()]  # UInt32 × 1.0: the backend's Float

    def peak(self) -> int:
        """The most events one lane took at one call site (0 when unarmed)."""
        return max((_int(dr.max(c)) for c in self.counts or ()), default=0)


def _float(x) -> float:
    """A Dr.Jit reduction's result (a width-1 array or a Python number) as a float."""
    return float(x[0]) if dr.is_array_v(x) else float(x)


def _int(x) -> int:
    """A Dr.Jit reduction's result (a width-1 array or a Python number) as an int."""
    return int(x[0]) if dr.is_array_v(x) else int(x)


def counters(mi_scene) -> list[LaneCounter]:
    """The `LaneCounter` of every rtfit Python medium in a loaded Mitsuba scene (sensor and shapes) and
    of its integrator (`rtfit.reference.fog_integrator` counts its path vertices)."""
    media = [s.get_medium() for s in mi_scene.sensors()] + [mi_scene.integrator()]
    for shape in mi_scene.shapes():
        media += [shape.interior_medium(), shape.exterior_medium()]
    out, seen = [], set()
    for m in media:
        c = getattr(m, "lane_counter", None)
        if isinstance(c, LaneCounter) and id(c) not in seen:
            seen.add(id(c))
            out.append(c)
    return out


class ArmedMedia:
    """Context manager: arm every counter for a launch of ``lanes`` lanes; `check` after the launch."""

    def __init__(self, counters_: list[LaneCounter], uint32_type, lanes: int):
        self.counters, self.uint32_type, self.lanes = counters_, uint32_type, lanes

    def __enter__(self):
        for c in self.counters:
            c.arm(self.uint32_type, self.lanes)
        return self

    def check(self) -> None:
        """Raise `PassBudgetExceeded` if any lane of the launch was stopped by its cap."""
        for c in self.counters:
            n = c.exhausted()
            if n:
                raise PassBudgetExceeded(
                    f"{n} of {self.lanes} lanes took more than {c.cap} medium events "
                    "(stopped; the pass is not stored)"
                )

    def __exit__(self, *exc):
        for c in self.counters:
            c.disarm()
        return False


def pass_budget_seconds() -> float:
    """``RTFIT_PASS_BUDGET_S`` (a positive number of seconds) or `DEFAULT_PASS_BUDGET_S`."""
    raw = os.environ.get("RTFIT_PASS_BUDGET_S")
    if raw is None or raw == "":
        return DEFAULT_PASS_BUDGET_S
    try:
        value = float(raw)
    except ValueError:
        value = float("nan")
    if not (value > 0 and value < float("inf")):
        raise ValueError(f"RTFIT_PASS_BUDGET_S must be a positive number of seconds (got {raw!r})")
    return value


class PassWatchdog:
    """Ends the process with one line if the pass it guards outlives ``seconds`` (see the module doc).

    ``what`` names the case and the pass (``"fog_terrain-e5-single pass 2 of 8"``). A thread waits on an
    event; a GPU kernel that never returns releases the GIL while the host waits for it, so the thread
    runs. ``_exit`` skips interpreter shutdown, which would wait for that kernel."""

    def __init__(self, what: str, seconds: float | None = None, exit_fn=None):
        self.what = what
        self.seconds = pass_budget_seconds() if seconds is None else float(seconds)
        self._exit = exit_fn or os._exit
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="rtfit-pass-watchdog", daemon=True)

    def _watch(self):
        if not self._done.wait(self.seconds):
            sys.stderr.write(
                f"rtfit: error: {self.what} ran past its budget of {self.seconds:g} s "
                "(RTFIT_PASS_BUDGET_S); finished passes are cached, a rerun resumes\n"
            )
            sys.stderr.flush()
            self._exit(1)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._done.set()
        self._thread.join()
        return False
