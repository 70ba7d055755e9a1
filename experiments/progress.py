"""Progress through the stages of a run (issue 37): a tqdm bar on a terminal, one line per step otherwise.

A stage with a known count — the experiments of ``rtfit run``, the scenes a family born on the engine
audits, the applicabilities whose references an audit renders, the cases whose rows it evaluates — is a
`Stage`. With ``enabled`` (the command's progress flag: stderr is a terminal, neither ``-q`` nor
``--no-progress``) and stderr a terminal (``sys.stderr.isatty()``), it draws one tqdm bar on stderr and each
step's line becomes the bar's postfix; otherwise each line goes to ``say`` unchanged (the INFO lines a pipe,
a log file or ``rtfit audit … --json -`` has always had). Nothing is ever written to stdout. The bars of the
passes themselves are `rtfit.reference.progress.progress_bar`'s; tqdm stacks the bars of nested stages.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable

__all__ = ["Stage"]

log = logging.getLogger("rtfit.experiments")


class Stage:
    """One stage of ``total`` steps called ``desc`` (``unit``: what a step is). ``note(line)``: a step
    starts (its line: the bar's postfix, else said); ``advance(line=None)``: a step is done (the bar moves;
    without a bar the line, if any, is said). A context manager: the bar is closed (and cleared) on exit."""

    def __init__(
        self,
        total: int,
        desc: str,
        *,
        enabled: bool,
        say: Callable[[str], object] | None = None,
        unit: str = "step",
    ):
        self._say = say or (lambda line: log.info("%s", line))
        self._bar = None
        if enabled and total > 0 and sys.stderr.isatty():
            from tqdm import tqdm

            # mininterval 0: a stage's steps are seconds apart; every one is drawn
            self._bar = tqdm(total=total, desc=desc, unit=unit, leave=False, file=sys.stderr, mininterval=0)

    @property
    def drawn(self) -> bool:
        """Whether this stage draws a bar (else it says lines)."""
        return self._bar is not None

    def note(self, line: str) -> None:
        if self._bar is not None:
            self._bar.set_postfix_str(line)
        else:
            self._say(line)

    def advance(self, line: str | None = None) -> None:
        if self._bar is not None:
            if line:
                self._bar.set_postfix_str(line, refresh=False)
            self._bar.update(1)
            if self._bar.n >= (self._bar.total or 0):  # the last step: the bar goes
                self.close()
        elif line:
            self._say(line)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> Stage:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
