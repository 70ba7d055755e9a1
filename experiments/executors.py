"""Choosing an executor by name: ``inline``, ``process`` or ``ray`` (the ``--executor`` option).

It sits above :mod:`.jobs` (the job model and the local executors) and :mod:`.ray_executor` (which builds
on the job model), so neither imports the other back.
"""

from __future__ import annotations

from .jobs import InlineExecutor, ProcessExecutor
from .ray_executor import RayExecutor

__all__ = ["EXECUTORS", "make_executor"]

EXECUTORS = ("inline", "process", "ray")


def make_executor(
    name: str = "inline",
    workers: int | None = None,
    progress: bool = False,
    address: str | None = None,
    gpus: list[int] | None = None,
):
    """``inline``, ``process`` (``gpus``: one worker per listed GPU) or ``ray`` (``address`` of an
    existing cluster, or a local one; without Ray installed, a one-line error naming the extra)."""
    if name == "inline":
        return InlineExecutor(progress)
    if name == "process":
        return ProcessExecutor(workers, progress, gpus=gpus)
    if name == "ray":
        return RayExecutor(address=address, workers=workers, progress=progress)
    raise ValueError(f"unknown executor {name!r} (expected one of: {', '.join(EXECUTORS)})")
