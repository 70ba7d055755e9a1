"""The environment of a user's scene as the environment families of `rtfit audit` see it.

Shared by the families that read a scene's environment (irradiance-bases: its unoccluded irradiance;
sdf-occlusion's sky-occlusion role and ambient-aperture's aperture fill: its occluded irradiance), so that
none imports another. An environment of either scene format becomes one `SceneEnvironment`: the loaded
Mitsuba emitter the references sample, its Mitsuba ``kind`` and, for a ``sunsky``, its sun:

* **Mitsuba XML** (`XmlScene.emitters[source]`, an ``envmap``, ``constant`` or ``sunsky`` emitter): the
  emitter Mitsuba instantiated from the file (`AuditSetup.emitters`), with its ``to_world`` and ``scale``;
* **rtfit TOML** (`Scene.lights[source]`, a light of `rtfit.scenes.ENVIRONMENT_KINDS`): the emitter rtfit's
  Mitsuba build made of it (`rtfit.reference.build.light_dicts`: ``constant_env`` → ``constant``,
  ``envmap`` → ``envmap`` rotated to +Z up, ``sunsky`` → ``sunsky``), named ``light<source>`` in the loaded
  scene. A ``constant_env`` that shares the scene with a sun of finite angular radius has no emitter of its
  own there (rtfit folds it into the sun's emitter: Mitsuba takes one environment emitter); it is then
  loaded alone from the same plugin dictionary (a constant's sampling reads no scene).

The sun of a ``sunsky`` is (unit direction towards it, angular radius in degrees: half the TOML
``sun_aperture_deg``, the XML emitter's own). What the bases read (`environment_of`, `environment_bases`,
`sh_l2_table`) is the environment baked from that emitter (`rtfit.reference.environments`).

The bake itself lives here too, once (`build_bases`: what an engine stores for each row of
`rtfit.realtime.environment_bases.METHODS`; `ROWS`: which baked coefficients each row reads), for the
irradiance-bases audit and its study (`rtfit.experiments.irradiance_bases_study`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.ambient_dice import fit_ambient_dice
from rtfit.realtime.environment_bases import METHODS
from rtfit.realtime.irradiance_bases import (
    CUBE_AXES,
    SH_MAX_ORDER,
    ambient_cube_from_axes,
    basis_irradiance,
    fibonacci_sphere,
    fit_ambient_cube_nnls,
    fit_window_lambda,
    latlong_samples,
    sh_from_constant,
    sh_from_disk,
    sh_project_latlong,
    zh3_from_sh,
)
from rtfit.realtime.spherical_gaussians import SG_COUNTS, SG_FITS, disc_samples, fit_sg_all
from rtfit.reference import environments as envs
from rtfit.reference.build import light_dicts
from rtfit.reference.environments import emitter_environment

from .audit import AuditError
from .audit_setup import AuditSetup
from .rows import Row

__all__ = [
    "BAKE_ROWS",
    "QUADRATURE_MIN_ROWS",
    "ROW",
    "ROWS",
    "SceneEnvironment",
    "build_bases",
    "environment_bases",
    "environment_of",
    "evaluate_row",
    "row_params",
    "scene_environment",
    "sh_l2_table",
    "supersample_for",
]

BAKE_ROWS = 128
"""Rows of the lat-long bake of a scene's environment emitter (× 2 columns)."""
QUADRATURE_MIN_ROWS = 256
"""The bases' own quadratures of the bake (Valve's axes, the NNLS fit) use at least this many rows."""
_FIT_NORMALS = 2048  # Fibonacci normals of the NNLS cube fit
_CFG = {"map_supersample": 2, "quadrature_min_rows": QUADRATURE_MIN_ROWS}
_TOML_KINDS = {"constant_env": "constant", "envmap": "envmap", "sunsky": "sunsky"}


@dataclass(frozen=True)
class SceneEnvironment:
    """One environment of the scene (module docstring): the Mitsuba plugin ``kind`` (``constant``,
    ``envmap``, ``sunsky``), the loaded ``emitter``, ``sun`` = (unit direction towards it, angular radius
    in degrees) for a sunsky (else None) and ``where`` (words: the file location or ``lights[i]``)."""

    kind: str
    emitter: Any
    sun: tuple[tuple[float, float, float], float] | None
    where: str


def _unit(v) -> tuple[float, float, float]:
    a = np.asarray(v, np.float64)
    a = a / np.linalg.norm(a)
    return (float(a[0]), float(a[1]), float(a[2]))


def _xml_environment(setup: AuditSetup, source: int, family: str) -> SceneEnvironment:
    light = setup.info.xml.emitters[source]
    emitter = setup.emitters[source]
    if emitter is None or not light.environment:
        raise AuditError(f"{family}: {light.kind} ({light.location}) is not an instantiated environment")
    sun = None
    if light.kind == "sunsky" and light.direction is not None:
        sun = (_unit(light.direction), float(light.angular_radius_deg or 0.0))
    return SceneEnvironment(light.kind, emitter, sun, light.location)


def _toml_environment(setup: AuditSetup, source: int, family: str) -> SceneEnvironment:
    light = setup.source.lights[source]
    where = f"lights[{source}]"
    kind = _TOML_KINDS.get(light.kind)
    if kind is None:
        raise AuditError(f"{family}: {light.kind} ({where}) is not an environment")
    mi = setup.mi
    name = f"light{source}"
    emitter = next((e for e in setup.scene.emitters() if e.id() == name), None)
    if emitter is None:  # a constant folded into a finite sun's emitter (module docstring)
        emitter = mi.load_dict(light_dicts(mi, light)[""])
    sun = None
    if kind == "sunsky":
        sun = (_unit(light.sun_direction), float(light.sun_aperture_deg) / 2)
    return SceneEnvironment(kind, emitter, sun, where)


def scene_environment(setup: AuditSetup, source: int, family: str = "the audit") -> SceneEnvironment:
    """The `SceneEnvironment` of the scene's environment ``source`` (an index into `XmlScene.emitters` for
    a Mitsuba XML scene, into `Scene.lights` for an rtfit TOML scene); `AuditError` naming ``family`` for
    another format or a part that is not an environment."""
    if setup.info.xml is not None:
        return _xml_environment(setup, source, family)
    if setup.info.format == "rtfit-toml" and setup.source is not None:
        return _toml_environment(setup, source, family)
    what = "the audit reads environments of Mitsuba XML and rtfit TOML scenes"
    raise AuditError(f"{family}: {what}, not {setup.info.format}")


def environment_of(setup: AuditSetup, source: int, rows: int = BAKE_ROWS, family: str = "irradiance-bases"):
    """The `Environment` of the scene's environment ``source`` (`scene_environment`, baked by
    `emitter_environment`: a constant as its radiance, else a lat-long map of ``rows`` × 2·``rows`` nodes; a
    sunsky's sun as an exact disc)."""
    env = scene_environment(setup, source, family)
    name = f"{env.kind} environment"
    return emitter_environment(setup.mi, env.emitter, env.kind, rows, sun=env.sun, name=name)


def environment_bases(env, backend: str | None = None) -> dict:
    """What an engine bakes from ``env`` (`build_bases` with the irradiance-bases family's settings): ``sh``
    (SH to L4, (25, 3)), the cubes, λ, … as that family's rows read them. ``backend``: the dense
    quadrature's (`rtfit.reference.environments.irradiance_quadrature`)."""
    return build_bases(env, _CFG, fit_normals=_FIT_NORMALS, backend=backend)


def sh_l2_table(bases: dict) -> np.ndarray:
    """The 27 SH L2 coefficients L_lm (W/m²), channel-major: the ``sh`` input of `environment_irradiance`
    and what ``sh-l2`` reads."""
    return np.ascontiguousarray(np.asarray(bases["sh"], np.float64)[:9].T.reshape(-1))


# ================================================================================ the bases' bake
def supersample_for(env, cfg: dict) -> int:
    """Quadrature supersampling of a map per axis: at least 2, and at least ``quadrature_min_rows`` rows."""
    if env.radiance_map is None:
        return 1
    return max(2, math.ceil(cfg["quadrature_min_rows"] / env.radiance_map.shape[0]))


def basis_row(
    method: str, coeffs: str | None, params: Mapping[str, str] | None = None, fitted_coeffs: bool = False
) -> Row:
    """One row of the comparison (`rows.Row`, its id the method's): a method of `METHODS` and where its
    inputs come from. ``coeffs`` (the row's ``source``): the key of `build_bases`'s result holding the baked
    coefficients the basis reads (None for the exact row, which reads the quadrature); ``params`` (the row's
    ``fitted_keys``): kernel parameter → key of the per-environment value fitted by `build_bases` (also the
    parameter's name in the results); ``fitted_coeffs``: the coefficients themselves are fitted (NNLS)
    rather than sampled or projected. The row is ``fitted`` when either is."""
    keys = dict(params or {})
    return Row(method, method=method, source=coeffs, fitted_keys=keys, fitted=bool(keys) or fitted_coeffs)


ROWS = (
    basis_row("cube-valve", "cube_valve"),
    basis_row("cube-nnls", "cube_nnls", fitted_coeffs=True),
    basis_row("sh-l1", "sh"),
    basis_row("sh-l1-geomerics", "sh"),
    basis_row("sh-l2", "sh"),
    basis_row("sh-l2-hann", "sh"),
    basis_row("sh-l2-lanczos", "sh"),
    basis_row("sh-l2-lambda", "sh", params={"lam": "lambda"}),
    basis_row("sh-l3", "sh"),
    basis_row("sh-l3-hann", "sh"),
    basis_row("sh-l3-lanczos", "sh"),
    basis_row("sh-l3-lambda", "sh", params={"lam": "lambda_l3"}),
    basis_row("sh-l4", "sh"),
    basis_row("sh-l4-hann", "sh"),
    basis_row("sh-l4-lanczos", "sh"),
    basis_row("sh-l4-lambda", "sh", params={"lam": "lambda_l4"}),
    basis_row("zh3", "zh3"),
    basis_row("zh3-lum", "zh3_lum"),
    basis_row("zh3-hallucinated", "sh"),
    *(basis_row(f"sg{n}-{f}", f"sg{n}_{f}", fitted_coeffs=f != "naive") for n in SG_COUNTS for f in SG_FITS),
    basis_row("ambient-dice", "ambient_dice", fitted_coeffs=True),
    basis_row("quadrature", None),
)
ROW = {r.method: r for r in ROWS}


def row_params(row: Row, bases: dict) -> dict[str, float]:
    """The kernel parameters of ``row`` for one environment's ``bases``."""
    return {p: bases[key] for p, key in row.fitted_keys.items()}


def evaluate_row(row: Row, bases: dict, normals, quadrature=None):
    """Irradiance (N, 3) of ``row`` at ``normals`` (N, 3) (or a tuple of Dr.Jit arrays for Dr.Jit normals);
    the exact row passes ``quadrature`` (the irradiance at the same normals) through its method."""
    m = METHODS[row.method]
    if m.exact:
        return np.asarray(m(NUMPY_OPS, {"irradiance": quadrature}), np.float64)
    return basis_irradiance(m, bases[row.source], normals, row_params(row, bases))


def build_bases(env, cfg: dict, fit_normals: int = 2048, backend: str | None = None) -> dict:
    """Every basis's coefficients for ``env`` (what an engine would bake), with the time each took."""
    out: dict = {"timing_ms": {}}
    t0 = time.perf_counter()
    order = (
        SH_MAX_ORDER  # one projection to L4 (25 rows) serves every SH row: lower orders read its first rows
    )
    sh = np.zeros(((order + 1) ** 2, 3))
    if env.constant is not None:
        sh += sh_from_constant(env.constant, order)
    if env.radiance_map is not None:
        sh += sh_project_latlong(env.radiance_map, cfg["map_supersample"], order)
    if env.sun is not None:
        s = env.sun
        sh += sh_from_disk(s.direction, math.radians(s.angular_radius_deg), np.asarray(s.irradiance), order)
    out["timing_ms"]["sh-projection"] = 1e3 * (time.perf_counter() - t0)
    out["sh"] = sh
    out["zh3"] = zh3_from_sh(sh)
    out["zh3_lum"] = zh3_from_sh(sh, shared_axis=True)
    t0 = time.perf_counter()
    ss = supersample_for(env, cfg)
    out["cube_valve"] = ambient_cube_from_axes(
        envs.irradiance_quadrature(env, np.array(CUBE_AXES), ss, backend)
    )
    out["timing_ms"]["cube-valve"] = 1e3 * (time.perf_counter() - t0)
    t0 = time.perf_counter()
    fn = fibonacci_sphere(fit_normals)
    target = envs.irradiance_quadrature(env, fn, ss, backend)
    out["cube_nnls"], out["cube_nnls_rms"] = fit_ambient_cube_nnls(fn, target)
    out["timing_ms"]["cube-nnls"] = 1e3 * (time.perf_counter() - t0)
    t0 = time.perf_counter()
    out["lambda"] = fit_window_lambda(sh)
    out["timing_ms"]["lambda-fit"] = 1e3 * (time.perf_counter() - t0)
    out["lambda_l3"] = out["lambda"]  # Â_3 = 0 and w_l does not depend on the order: the L2 answer
    out["lambda_l4"] = fit_window_lambda(sh, order=4)
    t0 = time.perf_counter()
    out["ambient_dice"], out["ambient_dice_rms"] = fit_ambient_dice(fn, target)
    out["timing_ms"]["ambient-dice"] = 1e3 * (time.perf_counter() - t0)
    t0 = time.perf_counter()
    samples = _radiance_samples(env, cfg)
    for n in SG_COUNTS:
        for f, amplitudes in fit_sg_all(n, *samples, constant=env.constant).items():
            out[f"sg{n}_{f}"] = amplitudes
    out["timing_ms"]["sg-fits"] = 1e3 * (time.perf_counter() - t0)
    return out


def _radiance_samples(env, cfg: dict):
    """The environment's radiance as samples (directions, solid-angle weights, radiance) for the SG fits: the
    bilinear map as `sh_project_latlong` sees it, plus the disc sun (`disc_samples`); the constant part is
    passed to `fit_sg` separately (closed form)."""
    parts = []
    if env.radiance_map is not None:
        parts.append(latlong_samples(env.radiance_map, cfg["map_supersample"]))
    if env.sun is not None:
        s = env.sun
        parts.append(disc_samples(s.direction, math.radians(s.angular_radius_deg), np.asarray(s.irradiance)))
    if not parts:
        return np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3))
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(3))
