"""The ``rtfit bench`` command (registered on the group in `rtfit.experiments.cli`): throughput of each
approximation and of the ground truth, printed as aligned tables and, with ``--json``, written as one
``rtfit.bench/1`` document."""

from __future__ import annotations

import json
import logging
import math
import time
from pathlib import Path

import click

import rtfit
from rtfit.reference import resolve_variant
from rtfit.reference.io import atomic_write_json

from . import scaling
from .atomic import writable_problem
from .cli_checks import fail, validated
from .cli_complete import complete_experiments
from .cli_options import VARIANT_CHOICES
from .registry import LIMITS, BenchContext
from .runner import created_now, device_description, use_variant_backend, versions

__all__ = ["BENCH_FORMAT", "bench_cmd", "bench_document"]


@click.command("bench")
@click.argument("experiment", shell_complete=complete_experiments)
@click.option("--variant", default="auto", show_default=True, type=click.Choice(VARIANT_CHOICES))
@click.option(
    "--size",
    type=click.IntRange(min=LIMITS["bench_size"].lo, max=LIMITS["bench_size"].hi),
    default=None,
    help="Elements per kernel launch (default: 2^22 on CPU, 2^24 on GPU).",
)
@click.option("--quick", is_flag=True, help="Fewer, smaller measurements.")
@click.option(
    "--json",
    "json_out",
    is_flag=False,
    flag_value="-",
    default=None,
    metavar="[FILE|-]",
    help="Also write the rows as JSON (format rtfit.bench/1) to FILE (atomically), or alone to stdout "
    "with '-' or no value (put --json last, or write --json=FILE).",
)
def bench_cmd(experiment, variant, size, quick, json_out):
    """Throughput of each approximation (Dr.Jit vs NumPy, same run) and of the ground truth;
    'executors': per-job overhead and sweep scaling of inline / process / Ray (docs/scale-out.md)."""
    target = _json_target(json_out)
    if experiment == "executors":
        name, variant = "executors", resolve_variant(variant)
        bench = scaling.bench
    else:
        (spec,), variant = validated([experiment], variant)
        name, bench = spec.name, spec.load().bench
    started, t0 = created_now(), time.perf_counter()
    use_variant_backend(variant)
    rows = bench(BenchContext(variant=variant, size=size, quick=quick))
    device = device_description(variant)
    if target != "-":
        click.echo(f"# rtfit bench {name} — {device}")
        _print_table(rows)
    if target is None:
        return
    header = dict(device=device, variant=variant, size=size, quick=quick, created=started)
    doc = bench_document(name, rows, **header, seconds=time.perf_counter() - t0)
    if target == "-":
        click.echo(json.dumps(doc, indent=2, allow_nan=False))
    else:
        atomic_write_json(target, doc)
        logging.getLogger("rtfit.experiments").info("bench %s: rows written to %s", name, target)


BENCH_FORMAT = "rtfit.bench/1"


def bench_document(
    name: str, rows: list[dict], *, device: str, variant: str, size, quick: bool, created: str, seconds: float
) -> dict:
    """``rtfit bench --json``: a header (format, experiment, rtfit version, date the bench started, its
    duration, device, variant, options, package versions) and the rows as objects, each with its own
    keys (rows of different keys are the separate tables of the text output). Non-finite numbers and
    absent cells are null."""
    return {
        "format": BENCH_FORMAT,
        "experiment": name,
        "rtfit": rtfit.__version__,
        "created": created,
        "seconds": round(seconds, 3),
        "device": device,
        "variant": variant,
        "size": size,
        "quick": quick,
        "versions": versions(),
        "rows": [{k: _json_value(v) for k, v in r.items()} for r in rows],
    }


def _json_value(v):
    if hasattr(v, "tolist"):  # NumPy scalars and arrays
        v = v.tolist()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, (list, tuple)):
        return [_json_value(x) for x in v]
    return v


def _json_target(value):
    """``--json`` checked before the benchmark runs: None, '-' (stdout) or a writable file path."""
    if value is None or value == "-":
        return value
    path = Path(value)
    if path.is_dir():
        fail(f"--json {value}: is a directory (name a file)")
    if not path.parent.is_dir():
        fail(f"--json {value}: no directory {path.parent}")
    problem = writable_problem(path.parent)  # /proc, a read-only mount: not after the benchmark (issue 32)
    if problem:
        fail(f"--json {value}: {problem}")
    return path


def _print_table(rows: list[dict]):
    """Rows as aligned columns; rows with different keys form separate tables, in order."""
    groups: list[list[dict]] = []
    for r in rows:
        if groups and list(groups[-1][0].keys()) == list(r.keys()):
            groups[-1].append(r)
        else:
            groups.append([r])
    for n, group in enumerate(groups):
        cols = list(group[0].keys())
        cells = [[_fmt(r.get(c)) for c in cols] for r in group]
        widths = [max(len(c), *(len(row[i]) for row in cells)) for i, c in enumerate(cols)]
        if n:
            click.echo("")
        click.echo("  ".join(c.ljust(w) for c, w in zip(cols, widths, strict=True)))
        for row in cells:
            click.echo("  ".join(v.ljust(w) for v, w in zip(row, widths, strict=True)))


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return "" if v is None else str(v)
