"""The per-pixel surface and medium quantities of ``rtfit compare --quantity irradiance|ao|transmittance``
(`rtfit.experiments.compare`), each from a reference pass the audit already uses, at the scene's own camera
(the pixel-centre G-buffer of its sensor at the frame's size, `rtfit.reference.gbuffer_points`):

* ``irradiance``: E = ∫ L_i (n·ω) dω (W/m², RGB) at each pixel's first visible hit with its shading normal
  (facing the camera): `rtfit.reference.total_irradiance.total_irradiance_pass` (direct light by Mitsuba's
  emitter sampling with MIS, delta lights included, plus every bounce of indirect light by ``path``).
  Pixels that see no surface are left out.
* ``ao``: ambient occlusion (unitless visibility 0…1: the cosine-weighted fraction of the hemisphere whose
  ray meets nothing within ``ao_radius``; ∞: nothing at all) at the same points:
  `rtfit.reference.occlusion.occlusion_pass` (quantity ``ao``), the ambient-occlusion family's reference.
  One grey value, copied to the three channels (their errors are the same estimate's). Pixels that see no
  surface are left out.
* ``transmittance``: T = exp(−∫σt ds) (unitless) along each pixel-centre camera ray from the camera to the
  first opaque surface, through every medium of the scene: per medium, its first stretch along the ray
  (`audit_media.medium_intervals`, as the height-fog family walks it) by ratio tracking
  (`rtfit.reference.medium_transmittance.transmittance_pass`; per channel where σt is chromatic), the
  media's T multiplied (their standard errors combined to first order: independent passes). A ray that
  never enters a medium has T = 1 exactly; one that leaves the scene inside an unbounded medium T = 0
  exactly. A scene without a medium cannot define it: refused (`refusal`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from rtfit.reference.cache import array_digest
from rtfit.reference.estimators import gbuffer_points
from rtfit.reference.medium_transmittance import transmittance_pass
from rtfit.reference.occlusion import occlusion_pass
from rtfit.reference.total_irradiance import total_irradiance_pass

from .audit import Applicability, AuditError
from .audit_media import MediumChannel, medium_intervals, opened_medium, sigma_t_at
from .audit_setup import AuditReference, AuditSetup, pooled_passes

__all__ = ["SURFACE_QUANTITIES", "quantity_reference", "refusal"]

SURFACE_QUANTITIES = {
    "irradiance": "irradiance E = ∫ L_i (n·ω) dω at the first hit, W/m² per RGB channel (direct + indirect)",
    "ao": "ambient occlusion at the first hit: unitless visibility 0…1 (cosine-weighted, within the radius)",
    "transmittance": "transmittance T = exp(−∫σt ds) along the camera ray to the first surface (unitless)",
}
FORMAT = 1


def refusal(quantity: str, info, ao_radius: float) -> str | None:
    """Why the scene (its inspection ``info``) cannot define ``quantity`` (one line), or None."""
    xml = info.xml
    if quantity == "transmittance" and (xml is None or not xml.media):
        return (
            "--quantity transmittance: the scene has no medium (no <medium>): its transmittance is 1 "
            "everywhere, nothing to compare"
        )
    if quantity == "ao" and not (ao_radius > 0):
        return f"--ao-radius {ao_radius}: expected a distance > 0 (inf: unbounded)"
    if quantity in ("irradiance", "ao") and xml is not None and not xml.shapes:
        return f"--quantity {quantity}: the scene has no shape: no surface to hold it"
    return None


def quantity_reference(
    setup: AuditSetup, quantity: str, ao_radius: float
) -> tuple[AuditReference, np.ndarray]:
    """The reference of ``quantity`` (module docstring) and the (H, W) mask of the pixels that hold it."""
    gb = setup.gbuffer
    if quantity == "transmittance":
        return _transmittance(setup)
    mask = np.asarray(gb.mask, bool)
    if not mask.any():
        raise AuditError(f"--quantity {quantity}: no pixel of the camera sees a surface")
    points, normals = gbuffer_points(gb, mask)
    mi, scene = setup.mi, setup.scene
    what = {
        "format": FORMAT,
        "kind": "compare",
        "quantity": quantity,
        "points": array_digest(points, normals),
    }
    if quantity == "irradiance":
        pooled = pooled_passes(
            setup,
            what,
            lambda n, s: total_irradiance_pass(mi, scene, points, normals, n, s),
            (-1, 3),
            "compare: irradiance",
        )
        integrator = "emitter sampling + path (direct with MIS, indirect by every bounce)"
        reason = "total irradiance at the visible point (delta lights included), pixel centre"
    else:
        what["radius"] = float(ao_radius) if math.isfinite(ao_radius) else None  # (JSON: no inf)

        def render(n: int, s: int):
            return occlusion_pass(mi, scene, points, normals, n, s, quantity="ao", max_distance=ao_radius)

        pooled = pooled_passes(setup, what, render, (-1,), "compare: ao", seed_label="ao-pass")
        integrator = "cosine-weighted visibility rays (occlusion_pass, quantity ao)"
        radius = "unbounded" if math.isinf(ao_radius) else f"radius {ao_radius:g}"
        reason = f"ambient occlusion within the {radius}, pixel centre"
    return pooled.reference(mask, SURFACE_QUANTITIES[quantity], integrator, reason), mask


def _transmittance(setup: AuditSetup) -> tuple[AuditReference, np.ndarray]:
    h, w = setup.gbuffer.view_dir.shape[:2]
    mean = np.ones((h * w, 3))
    var = np.zeros((h * w, 3))
    seconds, spp, passes, rendered, keys = 0.0, 0, 0, 0, []
    for k, medium in enumerate(setup.info.xml.media):
        app = Applicability("compare", "transmittance", f"medium {k} ({medium.type})", (), (), "", "", "", k)
        med, dirs, t_in, t_out = opened_medium(setup, app, "compare")
        origin = np.asarray(setup.sensor.world_transform().matrix, np.float64).reshape(4, 4)[:3, 3]
        if np.max(np.abs(origin - med.origin)) > 1e-6 * (1.0 + float(np.max(np.abs(origin)))):
            # a sensor moved to a pose (--camera-path poses.json): the rays start at its own origin
            med = dataclasses.replace(med, origin=origin)
            t_in, t_out = medium_intervals(setup.mi, med.scene, origin, dirs, med.ptr, med.on_sensor)
        enters = np.isfinite(t_in) & (t_out > t_in)
        ok = enters & np.isfinite(t_out)
        mk_mean, mk_var = np.ones((h * w, 3)), np.zeros((h * w, 3))
        mk_mean[enters & ~np.isfinite(t_out)] = 0.0  # leaves the scene inside an unbounded medium
        if ok.any():
            d, o = dirs[ok], med.origin
            mid = o + 0.5 * (t_in[ok] + t_out[ok])[:, None] * d
            st = sigma_t_at(setup.mi, med.medium, mid)
            chromatic = bool(np.any(np.abs(st - st[:, :1]) > 1e-6 * np.maximum(np.abs(st[:, :1]), 1e-30)))
            for c in range(3) if chromatic else (None,):
                tracked = med.medium if c is None else MediumChannel(med.medium, c)
                what = {
                    "format": FORMAT,
                    "kind": "compare",
                    "quantity": "transmittance",
                    "medium": k,
                    "channel": c,
                    "rays": array_digest(o, d, t_in[ok], t_out[ok]),
                }

                def render(n: int, s: int, tracked=tracked, d=d, o=o, near=t_in[ok], far=t_out[ok]):
                    return transmittance_pass(setup.mi, tracked, o, d, far, n, s, min_distance=near)

                pooled = pooled_passes(setup, what, render, (-1, 3), f"compare: transmittance of {app.part}")
                cols = slice(None) if c is None else slice(c, c + 1)
                mk_mean[np.flatnonzero(ok)[:, None], np.arange(3)[cols]] = pooled.mean[:, cols]
                mk_var[np.flatnonzero(ok)[:, None], np.arange(3)[cols]] = pooled.stderr[:, cols] ** 2
                seconds += pooled.seconds
                spp, passes = pooled.spp, pooled.passes
                rendered += pooled.passes_rendered
                keys.append(pooled.entry.key)
        # the product's variance to first order: Var(AB) ≈ B² Var A + A² Var B (independent passes)
        var = mk_mean**2 * var + mean**2 * mk_var
        mean = mean * mk_mean
    mask = np.ones((h, w), bool)
    ref = AuditReference(
        mean=mean.reshape(h, w, 3),
        stderr=np.sqrt(var).reshape(h, w, 3),
        spp=spp or setup.spp,
        passes=passes,
        passes_rendered=rendered,
        cache_key=",".join(keys),
        cache_path="",
        seconds=seconds,
        quantity=SURFACE_QUANTITIES["transmittance"],
        integrator="ratio tracking through each medium (Medium.get_scattering_coefficients)",
        integrator_reason="unbiased exp(−∫σt ds) per medium stretch, multiplied over the media; pixel centre",
        mask=mask,
    )
    return ref, mask
