"""``rtfit sweep SPEC.toml``: one experiment run over a grid (or a list) of configuration points.

Sweep file (TOML)::

    name = "wrap-vs-resolution"      # optional; default: the file's stem
    experiment = "half-lambert"      # a name from ``rtfit list``
    quick = true                     # optional: start from the quick configuration (default false)
    spp = 256                        # optional: reference samples per pixel for every point
    seed = 0                         # optional

    [fixed]                          # optional: configuration overrides shared by every point
    fit = true

    [grid]                           # optional: Cartesian product, key -> list of values
    resolution = [32, 48]
    scenes = [["diffuse_sphere_a1", "diffuse_sphere_a5"], ["diffuse_sphere_a5", "diffuse_sphere_a30"]]

    [[points]]                       # optional: explicit points, appended after the grid
    resolution = 64

Keys are the experiment's configuration keys (``configure(quick, spp)``; ``rtfit sweep --show-config
EXPERIMENT`` lists them with their defaults); every value is checked against the default's kind
before anything runs.

Each point is one job (``run_point``): the whole experiment runs on a worker with an inline
executor, and the worker returns its output files as plain data (bytes by relative path); the
driver writes them atomically to ``OUT/NAME/points/POINT/``. ``POINT`` is the point's index and a
hash of everything that determines its result (experiment, overrides, quick, spp, seed, variant), so
an interrupted or extended sweep reruns only the points that are missing, and renders only the
reference passes missing from the shared cache. The combined table is ``OUT/NAME/results.json``
(schema ``rtfit.results/1``: one case per point and experiment case, every point's checks, and a
failed check per point that could not be completed) with its report.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
import shutil
import tempfile
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from .atomic import atomic_directory
from .families import get_experiment
from .jobs import InlineExecutor, Job, Outcome
from .records import SCHEMA, Check, Results, ResultsError, from_json, to_json
from .registry import LIMITS, apply_overrides
from .report import write_report
from .report_index import write_index
from .results import RESULTS_FILE, load_results, write_results
from .run_settings import RunSettings
from .runner import created_now, device_description, experiment_dirs, run_experiment_into, versions

SWEEP_KEYS = {"name", "experiment", "quick", "spp", "seed", "fixed", "grid", "points", "description"}


class SweepError(ValueError):
    """A malformed sweep file: one line, ``FILE: KEY: problem``."""


@dataclass(frozen=True)
class SweepPoint:
    index: int
    overrides: dict
    key: str
    varying: tuple = ()  # the keys whose values differ between points (the point's label)

    @property
    def id(self) -> str:
        return f"p{self.index:03d}-{self.key[:8]}"

    @property
    def label(self) -> str:
        return (
            ", ".join(f"{k} = {_short(self.overrides[k])}" for k in self.varying if k in self.overrides)
            or "defaults"
        )


@dataclass
class Sweep:
    name: str
    experiment: str
    quick: bool = False
    spp: int | None = None
    seed: int = 0
    description: str = ""
    points: list[dict] = field(default_factory=list)

    def resolved_points(self, variant: str) -> list[SweepPoint]:
        keys = list(dict.fromkeys(k for p in self.points for k in p))
        varying = tuple(
            k for k in keys if len({json.dumps(p.get(k), sort_keys=True) for p in self.points}) > 1
        )
        return [
            SweepPoint(i, p, point_key(self.experiment, p, self.quick, self.spp, self.seed, variant), varying)
            for i, p in enumerate(self.points)
        ]


def _short(v) -> str:
    if isinstance(v, float):
        return f"{v:g}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_short(x) for x in v) + "]"
    return str(v)


def point_key(experiment: str, overrides: dict, quick: bool, spp, seed: int, variant: str) -> str:
    text = json.dumps(
        {
            "experiment": experiment,
            "overrides": overrides,
            "quick": quick,
            "spp": spp,
            "seed": seed,
            "variant": variant,
        },
        sort_keys=True,
    )
    return hashlib.sha256(text.encode()).hexdigest()


def load_sweep(path) -> Sweep:
    """Parse and validate a sweep file (every point against the experiment's configuration)."""
    path = Path(path)

    def fail(key: str, problem: str):
        raise SweepError(f"{path}: {key}: {problem}" if key else f"{path}: {problem}")

    try:
        doc = tomllib.loads(path.read_text())
    except FileNotFoundError:
        fail("", "no such sweep file")
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        fail("", f"not valid TOML ({str(e).splitlines()[0]})")
    for key in doc:
        if key not in SWEEP_KEYS:
            fail(key, f"unknown key (known: {', '.join(sorted(SWEEP_KEYS))})")
    if not isinstance(doc.get("experiment"), str):
        fail("experiment", "required: the experiment's name (see 'rtfit list')")
    try:
        spec = get_experiment(doc["experiment"])
    except ValueError as e:
        fail("experiment", str(e))
    quick = doc.get("quick", False)
    if not isinstance(quick, bool):
        fail("quick", "must be true or false")
    spp = doc.get("spp")
    if spp is not None and (not isinstance(spp, int) or isinstance(spp, bool) or spp < 2):
        fail("spp", "must be an integer ≥ 2")
    seed = doc.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool) or not 0 <= seed < 2**31:
        fail("seed", "must be an integer in [0, 2^31)")
    name = doc.get("name", path.stem)
    if not isinstance(name, str) or not name or "/" in name or name.startswith("."):
        fail("name", "must be a non-empty file name")
    fixed = doc.get("fixed", {})
    grid = doc.get("grid", {})
    listed = doc.get("points", [])
    if not isinstance(fixed, dict):
        fail("fixed", "must be a table of configuration keys")
    if not isinstance(grid, dict):
        fail("grid", "must be a table of key = [values]")
    if not isinstance(listed, list) or not all(isinstance(p, dict) for p in listed):
        fail("points", "must be an array of tables ([[points]])")
    for key, values in grid.items():
        if not isinstance(values, list) or not values:
            fail(f"grid.{key}", "must be a non-empty list of values")
        if key in fixed:  # which one wins would be an accident of dict order
            fail(f"grid.{key}", "is in [fixed] too: give it in one of them")
    count = math.prod(len(v) for v in grid.values()) * bool(grid) + len(listed)
    if count > LIMITS["sweep_points"].hi:  # counted before the grid is expanded
        fail("grid", f"{count} points: at most {LIMITS['sweep_points'].hi} (registry.LIMITS)")
    points = (
        [dict(fixed, **dict(zip(grid, combo, strict=True))) for combo in itertools.product(*grid.values())]
        if grid
        else []
    )
    points += [dict(fixed, **p) for p in listed]
    if not points:
        points = [dict(fixed)]
    defaults = spec.load().configure(quick, spp)
    for i, p in enumerate(points):
        try:
            apply_overrides(defaults, p, spec.name, declared=spec.config)
        except ValueError as e:
            fail(f"point {i}", str(e))
    seen = set()
    for i, p in enumerate(points):
        k = json.dumps(p, sort_keys=True)
        if k in seen:
            fail(f"point {i}", "duplicates an earlier point")
        seen.add(k)
    return Sweep(
        name=name,
        experiment=spec.name,
        quick=quick,
        spp=spp,
        seed=seed,
        description=str(doc.get("description", "")),
        points=points,
    )


# ------------------------------------------------------------------------------------------ workers
def run_point(experiment: str, overrides: dict, settings: RunSettings, point_key: str) -> dict:
    """Job body: run ``experiment`` with ``overrides`` and ``settings`` in a scratch directory on this
    worker and return its files as ``{relative path: bytes}`` (plain data, so it crosses any executor)."""
    spec = get_experiment(experiment)
    scratch = Path(tempfile.mkdtemp(prefix="rtfit-point-"))
    try:
        ctx = settings.context(scratch, InlineExecutor(), overrides)
        run_experiment_into(spec, scratch, ctx, "inline", extra_config={"sweep_point": point_key})
        return {
            "files": {
                p.relative_to(scratch).as_posix(): p.read_bytes()
                for p in sorted(scratch.rglob("*"))
                if p.is_file()
            }
        }
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


# ------------------------------------------------------------------------------------------- driver
@dataclass
class SweepSummary:
    directory: Path
    ran: list[str]
    resumed: list[str]
    failed: list[tuple[str, str]]  # (point id, one-line reason)


def _point_done(directory: Path, key: str) -> bool:
    """Whether ``directory`` holds valid results of the point with key ``key`` (else: run it again)."""
    try:
        return load_results(directory).config.sweep_point == key
    except ResultsError:
        return False


def _write_point(directory: Path, files: dict):
    with atomic_directory(directory) as tmp:
        for rel, data in files.items():
            target = Path(tmp) / rel
            if (
                target.resolve().parent != Path(tmp).resolve()
                and Path(tmp).resolve() not in target.resolve().parents
            ):
                raise ValueError(f"point output escapes its directory: {rel}")
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(data)


def run_sweep(
    sweep: Sweep,
    out: Path,
    *,
    variant: str,
    cache_dir: Path,
    executor,
    executor_name: str,
    log=lambda msg: None,
) -> SweepSummary:
    """Run every missing point through ``executor``; write each point and the combined report."""
    root = Path(out) / sweep.name
    (root / "points").mkdir(parents=True, exist_ok=True)
    points = sweep.resolved_points(variant)
    todo, resumed = [], []
    for p in points:
        (resumed if _point_done(root / "points" / p.id, p.key) else todo).append(p)
    log(
        f"sweep {sweep.name}: {len(points)} points of {sweep.experiment}, {len(resumed)} already done, "
        f"{len(todo)} to run on {executor_name}"
    )
    settings = RunSettings(Path(cache_dir), variant, sweep.spp, seed=sweep.seed, quick=sweep.quick)
    jobs = [
        Job(
            run_point,
            dict(experiment=sweep.experiment, overrides=p.overrides, settings=settings, point_key=p.key),
            label=p.id,
        )
        for p in todo
    ]
    outcomes: list[Outcome] = executor.run_all(jobs, desc=f"sweep {sweep.name}") if jobs else []
    failed = []
    for p, o in zip(todo, outcomes, strict=True):
        if o.ok:
            _write_point(root / "points" / p.id, o.value["files"])
        else:
            failed.append((p.id, o.error or "unknown error"))
    attempts = {p.id: o.attempts for p, o in zip(todo, outcomes, strict=True)}
    # The combined table lives in OUT/NAME/ itself (beside points/), so the suite index links it;
    # each file is written atomically.
    write_results(root, combined_results(sweep, points, root, dict(failed), attempts, variant, executor_name))
    write_report(root)
    write_index(Path(out), experiment_dirs(Path(out)))
    return SweepSummary(
        root, [p.id for p in todo if p.id not in dict(failed)], [p.id for p in resumed], failed
    )


def combined_results(
    sweep: Sweep,
    points: list[SweepPoint],
    root: Path,
    failed: dict,
    attempts: dict,
    variant: str,
    executor_name: str,
) -> Results:
    """One results document over all points: a case per (point, experiment case), every point's
    checks prefixed with its id, and a failed check for each point that could not be completed."""
    cases, checks, rows = [], [], []
    for p in points:
        path = root / "points" / p.id / RESULTS_FILE
        if p.id in failed or not path.is_file():
            checks.append(
                to_json(
                    Check(
                        name=f"{p.id} ({p.label}) completed",
                        value=failed.get(p.id, "missing"),
                        expected="completed",
                        passed=False,
                    )
                )
            )
            rows.append(f"| `{p.id}` | {p.label} | **failed**: {failed.get(p.id, 'missing')} |")
            continue
        doc = load_results(path.parent)
        for c in doc.cases:
            case = dataclasses.replace(
                c,
                id=f"{p.id}-{c.id}",
                label=f"{p.label} · {c.label}",
                parameters={
                    **{
                        f"sweep.{k}": _short(p.overrides[k])
                        if isinstance(p.overrides[k], list)
                        else p.overrides[k]
                        for k in p.varying
                        if k in p.overrides
                    },
                    **c.parameters,
                },
                approximations=[
                    dataclasses.replace(a, figures=[f"points/{p.id}/{f}" for f in a.figures])
                    for a in c.approximations
                ],
            )
            cases.append(to_json(case))
        checks += [to_json(dataclasses.replace(ch, name=f"{p.id}: {ch.name}")) for ch in doc.checks]
        ok = sum(ch.passed for ch in doc.checks)
        n = len(doc.checks)
        rows.append(
            f"| [`{p.id}`](points/{p.id}/report.html) | {p.label} | {ok}/{n} checks passed"
            f"{f', {attempts[p.id]} attempts' if attempts.get(p.id, 1) > 1 else ''} |"
        )
    table = "\n".join(["| Point | Overrides | Status |", "|:---|:---|:---|", *rows])
    n_failed = sum(
        1 for p in points if p.id in failed or not (root / "points" / p.id / "results.json").is_file()
    )
    summary = (
        f"Sweep **{sweep.name}** of experiment `{sweep.experiment}` over {len(points)} configuration points "
        f"({len(points) - n_failed} complete, {n_failed} failed). Each point's full report is linked below; "
        "the tables combine every point's cases."
    )
    doc = {
        "schema": SCHEMA,
        "experiment": f"sweep-{sweep.name}",
        "title": f"Sweep {sweep.name}: {get_experiment(sweep.experiment).title}",
        "summary": summary + (f"\n\n{sweep.description}" if sweep.description else ""),
        "created": created_now(),
        "config": {
            "experiment": sweep.experiment,
            "quick": sweep.quick,
            "spp": sweep.spp,
            "seed": sweep.seed,
            "variant": variant,
            "executor": executor_name,
            "points": len(points),
            **{
                f"fixed.{k}": v
                for k, v in (points[0].overrides if points else {}).items()
                if k not in (points[0].varying if points else ())
            },
        },
        "versions": versions(),
        "device": device_description(variant),
        "sections": [{"id": "points", "title": "Points", "text": table}],
        "cases": cases,
        "checks": checks,
    }
    return from_json(Results, doc, f"sweep {sweep.name}")


def show_config(experiment: str, quick: bool) -> str:
    """The experiment's configuration keys and defaults, as TOML-ish lines (for ``--show-config``)."""
    spec = get_experiment(experiment)
    cfg = spec.load().configure(quick, None)
    return "\n".join(f"{k} = {json.dumps(v)}" for k, v in cfg.items())
