"""rtfit.reference: Mitsuba 3 ground truth for rtfit scenes.

* `choose_integrator` — the cheapest integrator that is exact for a scene (the rule is documented
  in `rtfit.reference.integrators`).
* `mitsuba_scene_dict` / `load_mitsuba_scene` — the Mitsuba scene with only the plugins a scene needs.
* `ReferenceCache` / `ReferenceRequest` / `Reference` — resumable, content-addressed Monte Carlo
  references (radiance images point-sampled at pixel centres, irradiance probes), each with its
  per-element standard error.
* `render_gbuffer` — pixel-centre G-buffer (position, normal, depth, albedo, masks) for the same camera;
  `gbuffer_points` — its hits as float64 (points, unit normals), the per-point estimators' probes.
"""

from .build import load_mitsuba_scene, mitsuba_scene_dict, plugin_types
from .cache import Reference, ReferenceCache, ReferenceRequest, default_cache_dir, pool_passes
from .estimators import GBuffer, PassResult, gbuffer, gbuffer_points, irradiance_pass, radiance_pass
from .integrators import IntegratorChoice, can_interreflect, choose_integrator
from .variants import KNOWN_VARIANTS, backend_of, callers_variant, resolve_variant, use_variant


def render_gbuffer(scene, variant: str = "llvm_ad_rgb") -> GBuffer:
    """The pixel-centre G-buffer of ``scene``'s camera (not cached: it costs one ray per pixel)."""
    with callers_variant():  # the caller's Mitsuba variant is put back afterwards
        mi, mi_scene = load_mitsuba_scene(scene, variant)
        return gbuffer(mi, mi_scene)


__all__ = [
    "KNOWN_VARIANTS",
    "GBuffer",
    "IntegratorChoice",
    "PassResult",
    "Reference",
    "ReferenceCache",
    "ReferenceRequest",
    "backend_of",
    "can_interreflect",
    "choose_integrator",
    "default_cache_dir",
    "gbuffer",
    "gbuffer_points",
    "irradiance_pass",
    "load_mitsuba_scene",
    "mitsuba_scene_dict",
    "plugin_types",
    "pool_passes",
    "radiance_pass",
    "render_gbuffer",
    "resolve_variant",
    "use_variant",
]
