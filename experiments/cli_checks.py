"""Checks of what the user typed, run before an ``rtfit`` command starts anything: experiment names and
variant, configuration values, writable folders, executor and Ray address, GPU ids, ``--probe`` files,
report folders. Each failure is one line and exit status 2 (`UserError`)."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import click

from rtfit.reference import default_cache_dir, resolve_variant
from rtfit.reference.probe_maps import parse_probe_spec, probe_spec_problem
from rtfit.reference.variants import cuda_available

from .atomic import writable_problem
from .families import resolve_names, validate_config
from .ray_executor import RAY_EXTRA_HINT, check_address

__all__ = [
    "UserError",
    "check_executor",
    "check_report_folders",
    "config_ok",
    "fail",
    "parse_gpus",
    "probe_overrides",
    "validated",
    "writable_dir",
]


class UserError(click.ClickException):
    exit_code = 2


def fail(message: str):
    """Stop the command with ``message`` as its one error line (exit status 2)."""
    raise UserError(message)


def validated(names, variant: str):
    """Experiment specs and the resolved variant; a bad name or variant is a ValueError, which
    `main` prints as one line with exit status 2."""
    return resolve_names(names), resolve_variant(variant)


def probe_overrides(specs, quick: bool, probes) -> dict:
    """``--probe`` values as the ``probes`` configuration key (paths made absolute, a ``:MAPPING`` suffix
    kept), for experiments that declare it; none: no overrides."""
    if not probes:
        return {}
    for text in probes:  # the file's own problem first (one line), then whether any experiment takes it
        problem = probe_spec_problem(text)
        if problem:
            fail(f"--probe {text}: {problem}")
    without = []
    for s in specs:
        try:
            if "probes" not in validate_config(s.name, quick, None, {}):
                without.append(s.name)
        except ValueError as e:  # a bad default (e.g. a corrupt measured probe): the usual one line
            fail(f"{s.name}: {e}")
    if without:
        fail(
            f"--probe: {', '.join(without)} takes no probes (irradiance-bases runs on the audit engine's "
            "shipped scenes: put your probe in a scene as its envmap and run `rtfit audit SCENE`)"
        )
    out = []
    for text in probes:
        p = parse_probe_spec(text)
        path = str(Path(p.path).expanduser().absolute())
        out.append(f"{path}:{p.mapping}" if p.mapping else path)
    return {"probes": out}


def config_ok(experiment: str, quick: bool, spp, overrides: dict, where: str = ""):
    """``experiment``'s configuration with ``overrides``, every value checked against its declaration
    (`families.validate_config`: type, range, files readable): a one-line error otherwise."""
    try:
        validate_config(experiment, quick, spp, overrides)
    except ValueError as e:
        fail(f"{where}{experiment}: {e}")


def writable_dir(path, option: str) -> Path:
    """``path`` (``None``: the default cache directory, ``$RTFIT_CACHE`` or ``~/.cache/rtfit``) checked
    as a directory this process can create and write to, before anything runs: its nearest existing
    ancestor must be a directory, and a probe directory is made there and removed at once (``os.access``
    says yes to root on a read-only filesystem). Nothing else is created."""
    if path is None:
        path = default_cache_dir()
        if os.environ.get("RTFIT_CACHE"):
            option = "$RTFIT_CACHE"
    path = Path(path)
    problem = writable_problem(path)
    if problem is not None:
        fail(f"{option} {path}: {problem}")
    return path


def check_executor(executor: str, address):
    """``--executor`` with ``--address``: the address only for Ray, Ray installed, and the address (or
    ``$RAY_ADDRESS``) answering; a usage error otherwise."""
    if address and executor != "ray":
        raise click.UsageError("--address is for --executor ray")
    if executor == "ray":
        if importlib.util.find_spec("ray") is None:
            raise click.UsageError(RAY_EXTRA_HINT)
        if address:  # a wrong host or port: one line in seconds, before anything runs
            check_address(address)
        elif os.environ.get("RAY_ADDRESS"):  # Ray reads it by itself: the same check
            check_address(os.environ["RAY_ADDRESS"], option="$RAY_ADDRESS")


def parse_gpus(text, executor: str):
    """``--gpus 0,1`` as a list of distinct GPU ids (None when not given), only with the process executor and
    only where a CUDA GPU is found; a usage error otherwise."""
    if text is None:
        return None
    if executor != "process":
        raise click.UsageError("--gpus is for --executor process (Ray finds the GPUs itself)")
    try:
        ids = [int(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise click.UsageError(f"--gpus {text!r}: expected comma-separated GPU ids, e.g. 0,1") from None
    if not ids or min(ids) < 0 or len(set(ids)) != len(ids):
        raise click.UsageError(f"--gpus {text!r}: expected distinct non-negative GPU ids, e.g. 0,1")
    if not cuda_available():  # the workers would run on the CPU, silently (issue 32)
        raise click.UsageError(
            f"--gpus {text}: no CUDA GPU was found here (leave --gpus out to run on the CPU)"
        )
    return ids


def check_report_folders(folders: list[Path]) -> None:
    """Each folder the report is written into must be writable, checked before anything is written (a
    read-only or immutable folder ended in a traceback from the first atomic write: the re-check of issue
    32)."""
    for folder in folders:
        problem = writable_problem(folder)
        if problem:
            fail(f"{folder}: the report is written there, but {problem}")
