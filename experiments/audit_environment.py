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
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rtfit.reference.build import light_dicts
from rtfit.reference.environments import emitter_environment

from .audit_family import AuditError, AuditSetup
from .irradiance_bases import build_bases

__all__ = [
    "BAKE_ROWS",
    "QUADRATURE_MIN_ROWS",
    "SceneEnvironment",
    "environment_bases",
    "environment_of",
    "scene_environment",
    "sh_l2_table",
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


def environment_bases(env) -> dict:
    """What an engine bakes from ``env`` (`build_bases` with the irradiance-bases family's settings): ``sh``
    (SH to L4, (25, 3)), the cubes, λ, … as that family's rows read them."""
    return build_bases(env, _CFG, fit_normals=_FIT_NORMALS)


def sh_l2_table(bases: dict) -> np.ndarray:
    """The 27 SH L2 coefficients L_lm (W/m²), channel-major: the ``sh`` input of `environment_irradiance`
    and what ``sh-l2`` reads."""
    return np.ascontiguousarray(np.asarray(bases["sh"], np.float64)[:9].T.reshape(-1))
