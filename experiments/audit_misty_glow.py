r"""The ``misty-glow`` family in `rtfit audit`: the glow the camera sees around a point light in a scattering
medium, against the seed's Kawase bloom (000:628-652).

For each point light of the scene inside a homogeneous medium (the ``point-in-medium`` part, as for the
volumetric-lightning family; the light and its medium are read by `rtfit.experiments.audit_lit_media`), one
case ``lightK-glow`` on the pixels whose camera ray has a bounded stretch in that medium:

* **Reference**: the radiance at the camera, path traced with Mitsuba's ``volpathmis`` (all orders of
  scattering) through the run's sensor at the pixel centres, in passes through the pass cache. A point light
  is a delta: no pixel sees it directly, so the image *is* the glow.
* **Inputs** per pixel: the offset (``du``, ``dv``, film pixels) of the pixel centre from the light's image
  on the tangent plane of the camera, the pixel's solid angle ``omega_px`` (sr; pitch from the G-buffer's
  view directions), the light's attenuated irradiance at the camera ``e_direct`` = I·e^(−σ_t R)/R² per
  channel, and the quadrature of the light's single scattering along the ray (``single_scattering``,
  `rtfit.reference.single_scattering.point_single_scattering`, the volumetric-lightning family's exact
  row), plus ``intensity``, ``sigma_s``, ``sigma_t``, ``g`` and ``distance`` R for a user's approximation.
* **Rows**: `rtfit.realtime.misty_glow.METHODS`: the seed's four passes at scale 4 with the
  forward-scattering energy A₀ = e^(σ_s R) − 1 (channels' mean), then fitted; 1, 2, 6, 8 passes with
  scale and amplitude fitted; a Gaussian bloom; single scattering alone (a lower bound: the glow minus its
  multiply scattered part).

Assumptions (in each case's notes): nothing shadows the medium from the light; the light is in front of
the camera (else its image offset is set far outside the film and the bloom rows give 0).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from rtfit.realtime.misty_glow import KAWASE_PASSES, KAWASE_SEED_PASSES, METHODS
from rtfit.reference.cache import array_digest
from rtfit.reference.estimators import PassResult, radiance_pass
from rtfit.reference.single_scattering import point_single_scattering

from .audit import Applicability, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_lit_media import (
    NOTES,
    LitMedium,
    Stretches,
    light_parameters,
    lit_medium,
    quantity_inputs,
    stretches,
)
from .audit_media import RADIANCE_INTEGRATOR
from .audit_setup import AuditSetup, pooled_passes
from .records import Check, Section
from .shipped import ShippedScene, Sizes, Study, StudyContext

__all__ = [
    "FAMILY",
    "SCENES",
    "SIGMAS_T",
    "direct_irradiance",
    "glow_cases",
    "glow_inputs",
    "start_amplitude",
    "study",
]

FORMAT = 1
SIGMAS_T = (0.05, 0.25, 0.5, 1.0)
"""The shipped scenes' extinction σ_t (1/m): optical depth to the light τ = 4σ_t = 0.2 … 4."""
GS = (0.85,)
"""The shipped scenes' Henyey–Greenstein g."""
FAR = 1.0e6
"""The image offset (px) given where the light is behind the camera: far outside any film."""


_sizes = Sizes(full=(64, 64, 1024), quick=(24, 24, 256))


def _scene(sigma_t: float, g: float) -> ShippedScene:
    return _sizes.scene(
        "misty_glow_point.xml",
        f"point light 4 m away in a medium of σ_t = {sigma_t:g} /m (τ = {4 * sigma_t:g}), albedo 0.9, "
        f"g = {g:g}",
        defines={"sigma_t": f"{sigma_t:g}", "g": f"{g:g}"},
        name=f"s{sigma_t:g}-g{g:g}".replace(".", "p"),
        quick=sigma_t in (0.25, 1.0),
    )


SCENES = tuple(_scene(s, g) for s in SIGMAS_T for g in GS)
"""The scenes ``rtfit run misty-glow`` audits (scenes/library/misty_glow_point.xml, one per σ_t)."""


def direct_irradiance(intensity, sigma_t, distance: float) -> np.ndarray:
    """E_d = I·e^(−σ_t R)/R² (W/m²) per channel: the light's attenuated irradiance at the camera (0 where
    the exponential underflows; R floored at 1e-15 m: a camera on the light gives a huge finite value)."""
    r = max(float(distance), 1e-15)
    return np.asarray(intensity, np.float64) * np.exp(-np.asarray(sigma_t, np.float64) * r) / (r * r)


def start_amplitude(sigma_s, distance: float) -> float:
    """A₀ = e^(σ_s R) − 1 (channels' mean; module docstring), clipped into the amplitude's bounds: a
    dense medium overflows e^(σ_s R) and would give inf."""
    with np.errstate(over="ignore"):
        a0 = float(np.mean(np.expm1(np.asarray(sigma_s, np.float64) * float(distance))))
    return float(np.clip(a0, 1e-6, 1e5))


def _camera_frame(setup: AuditSetup) -> np.ndarray:
    """(3, 3): the sensor's local x, y, z axes in world space (columns; z: the view direction)."""
    m = np.asarray(setup.sensor.world_transform().matrix, np.float64).reshape(4, 4, -1)[..., 0]
    axes = m[:3, :3]
    return axes / np.linalg.norm(axes, axis=0, keepdims=True)


def glow_inputs(setup: AuditSetup, lit: LitMedium, rays: Stretches) -> dict[str, Any]:
    """``du``, ``dv`` (px), ``omega_px`` (sr) per masked pixel; ``distance`` R (m); ``e_direct`` (3,) W/m²."""
    frame = _camera_frame(setup)
    view = setup.gbuffer.view_dir.reshape(-1, 3).astype(np.float64)
    local = view @ frame
    tan_all = local[:, :2] / np.maximum(local[:, 2:3], 1e-12)
    h, w = setup.gbuffer.view_dir.shape[:2]
    tx = tan_all[:, 0].reshape(h, w)
    pitch = float(np.median(np.abs(np.diff(tx, axis=1)))) if w > 1 else 1.0
    to_light = lit.position - np.asarray(rays.origin)
    distance = float(np.linalg.norm(to_light))
    ll = to_light @ frame
    dl = rays.dirs @ frame
    t = dl[:, :2] / np.maximum(dl[:, 2:3], 1e-12)
    if ll[2] > 1e-9:
        off = (t - ll[:2] / ll[2]) / pitch
    else:  # the light is behind the camera: no image on the film
        off = np.full_like(t, FAR)
    omega = pitch**2 / (1.0 + t[:, 0] ** 2 + t[:, 1] ** 2) ** 1.5
    e_direct = direct_irradiance(lit.intensity, lit.sigma_t, distance)
    return {"du": off[:, 0], "dv": off[:, 1], "omega_px": omega, "distance": distance, "e_direct": e_direct}


def _reference(setup: AuditSetup, app: Applicability, lit: LitMedium, rays: Stretches, tag: str):
    mi = setup.mi
    integrator = mi.load_dict({"type": RADIANCE_INTEGRATOR})
    keep = rays.mask.ravel()
    what = {"format": FORMAT, "quantity": "glow-radiance", "light": app.source,
            "rays": array_digest(np.asarray(rays.origin), rays.dirs)}  # fmt: skip

    def render(spp: int, seed: int):
        r = radiance_pass(mi, lit.scene, spp, seed, integrator=integrator, sensor=setup.sensor)
        return PassResult(r.mean.reshape(-1, 3)[keep], r.var.reshape(-1, 3)[keep], r.spp, r.seed, r.seconds)

    pooled = pooled_passes(setup, what, render, (-1, 3), f"{tag}: {app.part} glow")
    return pooled.reference(
        rays.mask,
        quantity="radiance at the camera with the light's medium: the glow around the light (W/m²/sr)",
        integrator=RADIANCE_INTEGRATOR,
        integrator_reason="unbiased for the medium's multiple scattering (Mitsuba's volumetric path tracer)",
    )


def _params(a0: float) -> dict:
    amp = dataclasses.replace(METHODS["kawase-seed"].params["amplitude"], initial=a0, published=True)
    return {k: {"amplitude": amp} for k, m in METHODS.items() if "amplitude" in m.params}


def glow_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """One case per point light in a medium: its glow at the camera (module docstring)."""
    lit = lit_medium(setup, app, "point")
    rays = stretches(setup, app, lit)
    tag = f"light{app.source}"
    reference = _reference(setup, app, lit, rays, tag)
    g = glow_inputs(setup, lit, rays)
    single = [
        point_single_scattering(rays.origin, rays.dirs, rays.end, lit.position, float(lit.intensity[c]),
                                float(lit.sigma_s[c]), float(lit.sigma_t[c]), start=rays.start, g=lit.g)
        for c in range(3)
    ]  # fmt: skip
    channels = tuple(
        {
            "du": g["du"],
            "dv": g["dv"],
            "omega_px": g["omega_px"],
            "e_direct": float(g["e_direct"][c]),
            "distance": g["distance"],
            "single_scattering": single[c],
            **quantity_inputs(lit, c),
        }
        for c in range(3)
    )
    tau = float(np.mean(lit.sigma_t)) * g["distance"]
    a0 = start_amplitude(lit.sigma_s, float(g["distance"]))
    return [
        FamilyCase(
            id=f"{tag}-glow",
            label=f"{app.part}, glow at the camera",
            reference=reference,
            channel_inputs=channels,
            parameters={"light": app.part, **light_parameters(lit, rays), "optical_depth": tau, "A0": a0},
            units="W/m²/sr",
            notes=(
                NOTES[0],
                f"optical depth to the light τ = {tau:.3g}; the bloom rows start at A₀ = e^(σ_s R) − 1 = "
                f"{a0:.3g} (forward-scattering energy) and s = 4 px (the seed's ¼ downsample)",
                "single-scattering: the first-order glow by quadrature (no multiple scattering): a floor",
                f"{len(rays.start)} pixels; camera {'inside' if rays.inside else 'outside'} the medium",
            ),
            params=_params(a0),
            uncosted={"single-scattering": "its values come from the float64 quadrature outside its kernel"},
        )
    ]


FAMILY = AuditFamily(
    name="misty-glow",
    quantity="glow_radiance",
    cases=glow_cases,
    describe=(
        "Per point light inside a homogeneous medium, on the pixels whose camera ray has a stretch in that "
        "medium: the radiance at the camera path traced with volpathmis (all orders: the glow around the "
        "light, which a point light's delta never shows directly) against the seed's Kawase bloom of the "
        "light's direct image (4 passes, ¼ downsample, 000:628-652), 1–8 passes with scale and amplitude "
        "fitted, a Gaussian bloom, and the single-scattering quadrature (rtfit.reference.single_scattering)."
    ),
    formats=("mitsuba-xml",),
    rules=(
        Rule(
            "misty-glow",
            "glow around a light in a medium",
            ("point-in-medium",),
            "{part}: the medium's scattering spreads it into a glow",
            "the radiance at the camera around that light with its medium (W/m²/sr, RGB)",
            "volpathmis (all orders of scattering) at the pixel centres",
            supplies=frozenset({"du", "dv", "e_direct", "omega_px", "distance", "single_scattering"}),
        ),
    ),
)


# ------------------------------------------------------------------------------------------------ study
def _passes(row: str) -> int | None:
    """The Kawase passes N of a bloom row, None for the others."""
    base = row.removesuffix("-fitted")
    if base == "kawase-seed":
        return KAWASE_SEED_PASSES
    if base.startswith("kawase-") and int(base.split("-")[1]) in KAWASE_PASSES:
        return int(base.split("-")[1])
    return None


def _cost_lines(result, case) -> list[str]:
    """The cost-beside-error rows of one case (`study`)."""
    tau = case.parameters.get("optical_depth", float("nan"))
    lines = []
    for row_id, out in result.outcomes.get(case.id, {}).items():
        n = _passes(row_id)
        if not row_id.endswith("-fitted") or (n is None and not row_id.startswith("gaussian")):
            continue
        rmse = out.metrics["rmse"]
        ratio = rmse.value / rmse.noise_floor if rmse.noise_floor else float("nan")
        cost = result.costs.get(out.method.id, {}).get("ns_per_pixel")
        scale = float(out.parameters.get("scale", out.parameters.get("sigma", float("nan"))))
        reads = f"{4 * n / max(scale, 1e-6) ** 2:.3g}" if n is not None else "—"
        ns = f"{cost:.3g}" if cost else "—"
        lines.append(
            f"| {case.id} | {tau:.3g} | {row_id} | {n or '—'} | {scale:.3g} | {reads} | {ratio:.3g} | {ns} |"
        )
    return lines


def _single_check(result, case) -> Check | None:
    """The all-orders glow summed over the pixels is not below its single-scattering part (3 s.e.)."""
    single = result.outcomes.get(case.id, {}).get("single-scattering")
    if single is None:
        return None
    ref = case.reference.mean[case.mask]
    err = float(np.sqrt(np.sum(case.reference.stderr[case.mask] ** 2)))
    gap = float(np.sum(ref) - np.sum(single.image[case.mask]))
    return Check(
        name=f"{case.id}: glow >= its single-scattering part (sum over pixels, W/m²/sr)",
        value=gap,
        expected=f">= -3 s.e. = {-3 * err:.3g}",
        passed=gap >= -3 * err,
    )


def study(ctx: StudyContext) -> Study:
    """Cost beside error across the passes: per scene each fitted bloom's RMSE over the reference's noise
    floor, its fitted scale s and the bilinear reads per film pixel a GPU spends on it (4N/s² for N
    ping-pong passes over the film downsampled by s); and the check that the all-orders glow is not below
    its single-scattering part."""
    lines = [
        "| case | τ | row | N | s or σ (px) | GPU reads / film px (4N/s²) | RMSE / floor | kernel ns/px |",
        "|---|---|---|---|---|---|---|---|",
    ]
    checks = []
    for result in ctx.audits:
        for case in result.cases:
            lines += _cost_lines(result, case)
            check = _single_check(result, case)
            if check is not None:
                checks.append(check)
    text = (
        "Each fitted bloom's RMSE over the reference's noise floor beside its cost: the bilinear reads a GPU "
        "spends per film pixel on N ping-pong passes over the film downsampled by the fitted s (4N/s²; the "
        "seed's N = 4 at s = 4 reads 1 per film pixel, plus the down- and upsample), and the kernel text's "
        "measured ns per pixel (the per-pixel evaluation of the upsampled kernel, a sum of N(N+1)+1 tents "
        "per axis: not the GPU's bloom).\n\n" + "\n".join(lines)
    )
    return Study(
        sections=(Section("cost-passes", "Cost beside error across the passes", text),), checks=tuple(checks)
    )
