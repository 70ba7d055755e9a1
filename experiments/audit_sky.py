"""Occluded sky light of a scene's environment: the reference and the visibility bake that the sky families of
`rtfit audit` share (the sdf-occlusion sky role and ambient-aperture's aperture fill,
`audit_sky_occlusion`; the sh-sky-bent-normal family, `audit_sh_sky_bent_normal`), so that none imports
another and one environment is rendered and baked once per run.

* **Reference**: the sky's irradiance with visibility at each visible point x with unit normal n,
  E(x) = ∫_{H(n)} L_env(ω) V(x, ω) (n·ω) dω (W/m², RGB), V = 1 where the ray x + tω (t > 0) meets no shape,
  from the scene's own environment emitter (`audit_environment.scene_environment`; a ``sunsky``'s sky alone,
  its ``sun_scale`` set to 0 for the passes: the sun is a spherical light, the occluded-sphere-light role's),
  by `rtfit.reference.light_irradiance.environment_irradiance_pass` with the scene's shapes as occluders
  (Mitsuba's emitter sampling and the cosine hemisphere by the balance heuristic, each sample times Mitsuba's
  shadow ray), in independent passes through the pass cache, with per-pixel standard errors.
* **Visibility bake** (`rtfit.reference.occlusion.visibility_cap_pass`: unbounded ray casts against the
  scene's shapes, uniform on the hemisphere, pooled passes of their own seed): the visible fraction V_u, the
  cosine-weighted visibility V = (1/π)∫ V (n·ω) dω (an engine's AO of the sky: 1 unoccluded) and the bent
  normal b (the mean unoccluded direction; n where every ray is blocked), and the aperture
  r_a = acos(1 − V_u) (`ambient_aperture.aperture_from_visibility`). What an engine bakes per vertex or
  texel; its noise is independent of the reference's.
* ``sky_reference``: the reference alone (the same passes and cache entry), for a family that reads neither
  the bake nor the SH (ibl-samples: its own lights and shadow rays).
* **The sky's SH L2** (`audit_environment.sh_l2_table` of `environment_bases`: 27 coefficients L_lm,
  channel-major, W/m²; a sunsky's sky without its sun), what an engine's probe stores.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from rtfit.realtime.ambient_aperture import aperture_from_visibility
from rtfit.reference.cache import array_digest
from rtfit.reference.environments import emitter_scales
from rtfit.reference.estimators import gbuffer_points
from rtfit.reference.light_irradiance import environment_irradiance_pass
from rtfit.reference.occlusion import visibility_cap_pass

from .audit import Applicability, AuditError
from .audit_environment import environment_bases, environment_of, scene_environment, sh_l2_table
from .audit_setup import AuditReference, AuditSetup, pooled_passes

__all__ = ["FORMAT", "OccludedSky", "SkyReference", "occluded_sky", "sky_reference"]

FORMAT = 1
"""The key format of the sky and cap passes (every family reading them shares one set of passes)."""


@dataclass(frozen=True)
class OccludedSky:
    """The shared reference, bake and SH table of one environment (module docstring), over the visible points
    (``points``, ``normals``: (N, 3)): ``visible_fraction`` V_u, ``visibility`` V (cosine-weighted), ``bent``
    unit bent normals, ``aperture`` r_a (rad), ``sh`` the 27 SH L2 coefficients (W/m², channel-major),
    ``kind`` the emitter's plugin, ``bake_spp`` the rays per point of the bake, ``notes`` for the report."""

    reference: AuditReference
    kind: str
    points: np.ndarray
    normals: np.ndarray
    visible_fraction: np.ndarray
    visibility: np.ndarray
    bent: np.ndarray
    aperture: np.ndarray
    sh: np.ndarray
    bake_spp: int
    notes: tuple[str, ...]


def _sky_passes(setup: AuditSetup, source: int, emitter, kind: str, points, normals, label: str):
    """Pooled passes of the occluded sky irradiance (N, 3), W/m²."""
    sky_only = kind == "sunsky"

    def sky(spp: int, seed: int):
        if sky_only:
            with emitter_scales(setup.mi, emitter, sun_scale=0.0):
                return environment_irradiance_pass(
                    setup.mi, emitter, normals, spp, seed, mi_scene=setup.scene, points=points
                )
        return environment_irradiance_pass(
            setup.mi, emitter, normals, spp, seed, mi_scene=setup.scene, points=points
        )

    what = {"format": FORMAT, "quantity": "sky-irradiance-occluded", "emitter": source, "sky_only": sky_only}
    return pooled_passes(
        setup,
        {**what, "points": array_digest(points, normals)},
        sky,
        (-1, 3),
        f"sky: {label}",
        seed_label="sky-pass",
    )


def _cap_passes(setup: AuditSetup, points, normals, label: str):
    """Pooled passes of the visibility bake (N, 5)."""

    def caps(spp: int, seed: int):
        return visibility_cap_pass(setup.mi, setup.scene, points, normals, spp, seed)

    return pooled_passes(
        setup,
        {"format": FORMAT, "quantity": "visibility-caps", "points": array_digest(points, normals)},
        caps,
        (-1, 5),
        f"caps: {label}",
        seed_label="cap-pass",
    )


@dataclass(frozen=True)
class SkyReference:
    """The occluded sky irradiance of one environment alone (no bake, no SH): its pooled ``passes``, the
    Mitsuba ``kind``, the visible ``points`` and ``normals`` (N, 3)."""

    passes: Any
    kind: str
    points: np.ndarray
    normals: np.ndarray

    def reference(self, mask: np.ndarray, extra_seconds: float = 0.0) -> AuditReference:
        """The `AuditReference` of the passes on ``mask``."""
        kind = self.kind
        return self.passes.reference(
            mask,
            quantity="sky irradiance with visibility E = ∫ L_env V (n·ω) dω at the visible points (W/m²)",
            integrator="environment irradiance with shadow rays (MIS: emitter + cosine sampling)",
            integrator_reason=(
                f"{kind}"
                + (" (sky only: sun_scale 0)" if kind == "sunsky" else "")
                + ": the environment emitter alone, Mitsuba's Emitter.sample_direction and the cosine "
                "hemisphere by the balance heuristic, each sample times Mitsuba's shadow ray against the "
                "scene's shapes"
            ),
            extra_seconds=extra_seconds,
        )


def sky_reference(setup: AuditSetup, app: Applicability, family: str) -> SkyReference:
    """The occluded sky irradiance of the environment ``app.source`` alone: the passes `occluded_sky` pools
    (the same cache entry), for a family that reads neither the visibility bake nor the SH (ibl-samples).
    `AuditError` naming ``family`` where ``app`` is no environment."""
    if app.source is None:
        raise AuditError(f"{family}: {app.part} is not an environment of the scene")
    scene_env = scene_environment(setup, app.source, family)
    points, normals = gbuffer_points(setup.gbuffer, setup.mask)
    sky = _sky_passes(setup, app.source, scene_env.emitter, scene_env.kind, points, normals, app.part)
    return SkyReference(sky, scene_env.kind, points, normals)


_MEMO: dict[str, Any] = {}
MEMOS = (_MEMO,)
"""This module's process-wide memos, emptied between the experiments of a suite (`runner.forget_memos`)."""


def occluded_sky(setup: AuditSetup, app: Applicability, family: str) -> OccludedSky:
    """The reference, the bake and the SH table for the environment ``app.source`` (module docstring);
    computed once per run and environment (every sky family reads them). `AuditError` naming ``family``
    where ``app`` is no environment."""
    if app.source is None:
        raise AuditError(f"{family}: {app.part} is not an environment of the scene")
    key = (id(setup), app.source)
    if _MEMO.get("key") == key and _MEMO.get("setup") is setup:
        return _MEMO["value"]
    base = sky_reference(setup, app, family)
    points, normals, kind = base.points, base.normals, base.kind
    bake = _cap_passes(setup, points, normals, app.part)
    caps = bake.mean
    v_u = np.clip(caps[:, 0], 0.0, 1.0)
    vis = np.clip(caps[:, 1], 0.0, 1.0)
    bent = caps[:, 2:5]
    length = np.linalg.norm(bent, axis=1, keepdims=True)
    bent = np.where(length > 1e-12, bent / np.maximum(length, 1e-30), normals)  # fully occluded: n
    aperture = np.asarray(aperture_from_visibility(v_u), np.float64)
    env = environment_of(setup, app.source, family=family)
    sh27 = sh_l2_table(environment_bases(replace(env, sun=None)))
    ref = base.reference(setup.mask, extra_seconds=bake.seconds)
    notes = (
        "occluded: the scene's shapes block the sky (one bounce: no interreflection)",
        "E_SH: the environment's SH L2 projection"
        + (" (the sky without its sun)" if kind == "sunsky" else "")
        + ", as the irradiance-bases family bakes it",
        f"visibility bake: {int(bake.spp)} uniform hemisphere rays per point (unbounded), in passes of "
        f"their own seed; mean cosine-weighted visibility {float(vis.mean()):.4g}",
    )
    value = OccludedSky(ref, kind, points, normals, v_u, vis, bent, aperture, sh27, int(bake.spp), notes)
    _MEMO.clear()
    _MEMO.update(key=key, setup=setup, value=value)
    return value
