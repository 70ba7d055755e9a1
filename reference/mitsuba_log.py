"""Mitsuba's log through rtfit's logging (issue 32).

Mitsuba writes its warnings (``WARN [Sphere] 'to_world' transform shouldn't contain non-uniform scaling!``)
to **stdout**, with ANSI colour codes even when stdout is a file or a pipe: they mixed into ``rtfit audit
--list`` output and into reports captured from stdout. `route_mitsuba_log(mi)` replaces the appenders of
Mitsuba's process-wide logger (once per process) by one that hands each message to the ``rtfit.mitsuba``
logger: rtfit's command line prints it on stderr as one ``rtfit: warning: mitsuba: [Sphere] …`` line
(`rtfit.experiments.cli`'s handler), with the timestamp and level prefix and every colour code removed;
a library caller's own logging configuration decides where it goes. Levels: Mitsuba's Error → ERROR,
Warn → WARNING, Info/Debug/Trace → DEBUG. Progress bars are dropped (rtfit draws its own).
"""

from __future__ import annotations

import logging
import re

__all__ = ["plain_text", "route_mitsuba_log"]

log = logging.getLogger("rtfit.mitsuba")
_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")
_PREFIX = re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d\s+(?:TRACE|DEBUG|INFO|WARN|ERROR)\s+")
_routed: list[object] = []  # the appender installed (kept alive here), once per process


def plain_text(text: str) -> str:
    """A Mitsuba log message as one plain line: colour codes, the timestamp and level prefix removed."""
    text = _PREFIX.sub("", _ANSI.sub("", str(text)).strip())
    return " ".join(text.split())


def route_mitsuba_log(mi) -> None:
    """Route Mitsuba's log (module docstring) through ``logging``; idempotent. ``mi``: the ``mitsuba``
    module with a variant set (its logger exists from then on)."""
    if _routed:
        return
    logger = mi.logger() if hasattr(mi, "logger") else mi.Thread.thread().logger()
    levels = {mi.LogLevel.Error: logging.ERROR, mi.LogLevel.Warn: logging.WARNING}

    class _ToLogging(mi.Appender):
        def append(self, level, text):
            log.log(levels.get(level, logging.DEBUG), "mitsuba: %s", plain_text(text))

        def log_progress(self, *args, **kwargs):
            pass

    appender = _ToLogging()
    logger.clear_appenders()
    logger.add_appender(appender)
    _routed.append(appender)
