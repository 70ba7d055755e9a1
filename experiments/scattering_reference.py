"""The pieces of single scattering from a light in a medium that several modules share: the reference render
job of a single-scattering scene, the fits' residual scale and closed-form level fit (the light-cones
experiment; `fit_level` also the volumetric-lightning study's fixed-core models), the reference checks of
Mitsuba's single scattering against the quadrature of `rtfit.reference.single_scattering`, and the point
light's fit parameters (`fit_params`: start and bounds of the stable form's (i, a) from a case's physics),
which the volumetric-lightning audit reads.

A pixel's reference is Mitsuba ``volpathmis`` with max_depth 2 (single scattering) of a light inside a
homogeneous medium box around the camera; the checks compare it with the quadrature on the pixels whose
reference resolves the light's peak (each experiment's own mask).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from rtfit.fitting import Param
from rtfit.realtime.volumetric_lightning import METHODS
from rtfit.reference import (
    ReferenceCache,
    ReferenceRequest,
    load_mitsuba_scene,
    radiance_pass,
    render_gbuffer,
)
from rtfit.reference.single_scattering import FOUR_PI
from rtfit.scenes import parse_scene_text, scene_to_toml

from .cost import rate_row
from .jobs import Job, reference_args
from .records import Check
from .zchecks import pixel_z_checks

__all__ = [
    "FIT_METHOD",
    "FIT_RANGE",
    "fit_level",
    "fit_params",
    "reference_checks",
    "reference_rate_row",
    "render_job",
    "render_references",
    "residual_scale",
]


def fit_level(model: np.ndarray, ref: np.ndarray) -> float:
    """The level i (closed-form weighted least squares, weights of `fit_data`) of a model F/i = ``model``."""
    w = 1.0 / residual_scale(ref)
    return float(np.sum(w * w * model * ref) / np.sum(w * w * model * model))


def render_job(
    scene_toml: str, spp: int, pass_spp: int, seed: int, variant: str, cache_dir: str, progress: bool = False
) -> dict:
    """Job: one cached reference image and the pixel-centre view directions of its camera."""
    scene = parse_scene_text(scene_toml)
    ref = ReferenceCache(cache_dir).get(
        ReferenceRequest(scene=scene, spp=spp, pass_spp=pass_spp, seed=seed, variant=variant),
        progress=progress,
        label=scene.name,
    )
    gb = render_gbuffer(scene, variant)
    return {"image": ref, "view_dir": gb.view_dir.astype(np.float64)}


def render_references(ctx, cfg: dict, scenes: dict) -> dict:
    """Every case's `render_job` (``cfg``'s spp and pass_spp) on the run's executor: case id → its result."""
    jobs = [
        Job(
            render_job,
            dict(
                scene_toml=scene_to_toml(scene),
                **reference_args(ctx, cfg),
                progress=ctx.progress,
            ),
            label=cid,
        )
        for cid, scene in scenes.items()
    ]
    ctx.log(f"rendering {len(jobs)} references")
    return dict(zip(scenes, ctx.executor.map(jobs, desc="references"), strict=True))


def reference_rate_row(what: str, scene, spp: int, variant: str) -> dict:
    """The bench row of the reference's samples/s on ``scene`` (its camera's pixels × ``spp``): one warm-up
    pass (kernel compile), then the best of two."""
    mi, ms = load_mitsuba_scene(scene, variant)
    radiance_pass(mi, ms, spp, 0)
    t = min(radiance_pass(mi, ms, spp, k + 1).seconds for k in range(2))
    w, h = scene.camera.width, scene.camera.height
    samples = w * h * spp
    return rate_row(f"{what} ({w}×{h}, {spp} spp)", variant, samples, t)


def residual_scale(ref: np.ndarray) -> np.ndarray:
    """The fits' residual scale: 2 % of the reference plus 1 % of its mean (relative error, not dominated by
    the pixels next to the light)."""
    return 0.02 * np.abs(ref) + 0.01 * float(np.mean(np.abs(ref)))


def reference_checks(cid: str, ref, exact: np.ndarray, mask: np.ndarray, model_se: np.ndarray) -> list[Check]:
    """Mitsuba against the quadrature on the resolved pixels (`CORE_EVENTS_MIN`): z-scores of unit spread,
    pooled z, largest |z| (Šidák). Each z uses max(the sample standard error, the estimator's analytic one,
    `model_stderr`): the sample's is low exactly when the rare near-light samples happened to be few (the
    two agree to a median ratio 1.00 where the peak is well sampled; D = 1 m, σ_t = 0.01 /m, 48×32)."""
    sig = np.sqrt(np.maximum(ref.sigma()[..., 0] ** 2, model_se**2))[mask]
    diff = ref.mean[..., 0][mask] - exact[mask]
    z = diff / sig
    pooled = float(np.sum(diff) / math.sqrt(np.sum(sig**2)))
    names = (
        f"reference check {cid}: Mitsuba single scattering = σ_s/(4π)∫ I·T/r² ds (quadrature): "
        f"z-score spread ({z.size} pixels)",
        f"reference check {cid}: pooled z-score of (Mitsuba − quadrature)",
        f"reference check {cid}: largest |z|",
    )
    return pixel_z_checks(z, pooled, names, 0.2)


# --------------------------------------------------------------------------- the point light's fit
FIT_METHOD = "stable"
"""The method whose (i, a) are fitted per case."""

FIT_RANGE = {"i": (1e-4, 1e4), "a": (1e-3, 1e2)}
"""Fits start at a₀ = 100/D² (core radius D/10) and i₀ = a₀·σ_s·I/(4π) (the far field of the true light),
bounded to these factors of the start: the core radius 1/√a stays within [D/100, 3.2·D]. The physics, a
point light, would take a → ∞; a core below D/100 changes only the few pixels whose rays pass that close
(none in the quick configuration, whose closest ray passes at 0.026·D)."""


def fit_params(case: dict) -> dict[str, Param]:
    a0 = 100.0 / case["distance"] ** 2
    start = {"a": a0, "i": a0 * case["sigma_s"] * case["intensity"] / FOUR_PI}
    spec = METHODS[FIT_METHOD].params
    return {
        k: dataclasses.replace(spec[k], initial=x, lower=x * FIT_RANGE[k][0], upper=x * FIT_RANGE[k][1])
        for k, x in start.items()
    }
