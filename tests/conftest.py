"""Shared fixtures. Every test that touches Mitsuba asks for the variant it needs (no test relies on
state another test left behind), and Dr.Jit's JIT state is flushed between tests."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

from rtfit.scenes.model import Camera, Diffuse, ReferenceSettings, Scene, Sphere, SphereLight

# Hypothesis: derandomised in CI (the same examples every run, so a red CI is reproducible from its log),
# random locally (new examples each run). HYPOTHESIS_PROFILE overrides. No deadline: Dr.Jit compiles a
# kernel on its first call, which a per-example deadline would misread as slowness.
settings.register_profile(
    "ci", derandomize=True, deadline=None, print_blob=True, suppress_health_check=[HealthCheck.too_slow]
)
settings.register_profile("dev", deadline=None, print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci" if os.environ.get("CI") else "dev"))


@pytest.fixture(autouse=True)
def _costs_timed_on_their_repeats_only(monkeypatch):
    """Each method's cost (`rtfit.experiments.cost`) is the median of its ``repeats`` timed calls, taken here
    without the run's further calls until ``min_seconds`` (0.2 s) have passed: the suite asserts costs only
    as present and positive, never their values, and the floor cost ≥ 0.2 s per timed method (7.5 s of one
    audit of the sphere-light scene). Subprocesses a test starts keep the floor unless they patch it too."""
    from rtfit.experiments import cost

    median_time = cost._median_time
    monkeypatch.setattr(
        cost, "_median_time", lambda call, repeats, min_seconds: median_time(call, repeats, 0.0)
    )


@pytest.fixture()
def mi():
    import drjit as dr
    import mitsuba

    mitsuba.set_variant("llvm_ad_rgb")
    yield mitsuba
    dr.flush_malloc_cache()


def sphere_scene(
    alpha_deg: float = 5.0,
    distance: float = 20.0,
    res: int = 48,
    lights=None,
    transport: str = "direct",
    reflectance: float = 1.0,
    shapes=None,
) -> Scene:
    """A white unit sphere seen from −y, lit from +x by a sphere light of angular radius ``alpha_deg``
    at the origin (radiance 1/sin²α: irradiance π at normal incidence)."""
    sin_a = math.sin(math.radians(alpha_deg))
    if lights is None:
        lights = (
            SphereLight(center=(distance, 0.0, 0.0), radius=distance * sin_a, radiance=(1 / sin_a**2,) * 3),
        )
    return Scene(
        name="test-sphere",
        camera=Camera(origin=(0.0, -6.0, 0.0), target=(0.0, 0.0, 0.0), fov_deg=24.0, width=res, height=res),
        shapes=shapes
        if shapes is not None
        else (Sphere(center=(0.0, 0.0, 0.0), radius=1.0, material=Diffuse((reflectance,) * 3)),),
        lights=tuple(lights),
        reference=ReferenceSettings(transport=transport),
    )


def upper_hemisphere_nodes(n_mu: int, n_phi: int):
    """Quadrature nodes of the upper hemisphere: Gauss–Legendre in μ = cos θ ∈ (0, 1) × midpoint rule in φ.
    Returns unit directions (n_mu·n_phi, 3) and solid-angle weights summing to 2π."""
    x, wx = np.polynomial.legendre.leggauss(n_mu)
    mu, wmu = 0.5 * (x + 1), 0.5 * wx
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    mm, pp = np.meshgrid(mu, phi, indexing="ij")
    st = np.sqrt(1 - mm**2)
    d = np.stack([st * np.cos(pp), st * np.sin(pp), mm], -1).reshape(-1, 3)
    w = (wmu[:, None] * np.full(n_phi, 2 * np.pi / n_phi)[None, :]).reshape(-1)
    return d, w


def run_tiny_experiment(name: str, tmp_path, overrides: dict):
    """Run experiment ``name`` (quick, llvm_ad_rgb, inline, seed 0) with configuration ``overrides`` into
    ``tmp_path/out`` with its own cache, and return its loaded results record."""
    from rtfit.experiments.families import get_experiment
    from rtfit.experiments.results import load_results
    from rtfit.experiments.run_settings import RunSettings
    from rtfit.experiments.runner import run_experiments

    run_experiments(
        [get_experiment(name)],
        tmp_path / "out",
        RunSettings(tmp_path / "cache", "llvm_ad_rgb", quick=True),
        overrides=overrides,
    )
    return load_results(tmp_path / "out" / name)
