"""Shared fixtures. Every test that touches Mitsuba asks for the variant it needs (no test relies on
state another test left behind), and Dr.Jit's JIT state is flushed between tests."""

from __future__ import annotations

import math

import pytest

from rtfit.scenes.model import Camera, Diffuse, ReferenceSettings, Scene, Sphere, SphereLight


@pytest.fixture()
def mi():
    import drjit as dr
    import mitsuba

    mitsuba.set_variant("llvm_ad_rgb")
    yield mitsuba
    dr.flush_malloc_cache()


def sphere_scene(alpha_deg: float = 5.0, distance: float = 20.0, res: int = 48, lights=None,
                 transport: str = "direct", reflectance: float = 1.0, shapes=None) -> Scene:
    """A white unit sphere seen from −y, lit from +x by a sphere light of angular radius ``alpha_deg``
    at the origin (radiance 1/sin²α: irradiance π at normal incidence)."""
    sin_a = math.sin(math.radians(alpha_deg))
    if lights is None:
        lights = (SphereLight(center=(distance, 0.0, 0.0), radius=distance * sin_a, radiance=(1 / sin_a**2,) * 3),)
    return Scene(
        name="test-sphere",
        camera=Camera(origin=(0.0, -6.0, 0.0), target=(0.0, 0.0, 0.0), fov_deg=24.0, width=res, height=res),
        shapes=shapes if shapes is not None else (Sphere(center=(0.0, 0.0, 0.0), radius=1.0,
                                                         material=Diffuse((reflectance,) * 3)),),
        lights=tuple(lights),
        reference=ReferenceSettings(transport=transport),
    )
