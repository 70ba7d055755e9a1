"""What the environment-maps and probe-specular audits share: the pixels that see one reflective shape, their
path-traced radiance and BSDF lobes, and a cube-map probe's capture from a point inside the scene.

Each family keeps its own cache ``FORMAT`` (the first field of every key here) and its own sample counts;
the keys, labels and seeds are the ones both families wrote before (their pass caches stay valid). Family
modules import this one, never each other.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rtfit.realtime.environment_maps import cube_texels
from rtfit.reference.cache import array_digest
from rtfit.reference.estimators import sub_seed
from rtfit.reference.reflective_shapes import SurfaceLobes, ray_radiance_pass, surface_lobes

from .audit import Applicability
from .audit_geometry import shape_view, visible_subset
from .audit_setup import AuditSetup, PooledPasses, pooled_passes

__all__ = ["SeenShape", "probe_capture", "seen_shape", "shape_radiance", "unit_cube_texels"]


@dataclass(frozen=True)
class SeenShape:
    """The pixels whose camera ray first hits the shape ``index``: their ``mask`` (H, W), and per pixel
    (row-major) the ray ``origins``, unit ``dirs`` and first-hit ``points`` (N, 3); ``centre``: the
    shape's bounding-box centre, ``probe``: ``--probe-at`` where given, else ``centre``."""

    index: int
    mask: np.ndarray
    origins: np.ndarray
    dirs: np.ndarray
    points: np.ndarray
    centre: np.ndarray
    probe: np.ndarray


def seen_shape(setup: AuditSetup, index: int, shape) -> SeenShape | None:
    """The pixels that see ``shape``, the scene's shape ``index`` (`SeenShape`); None where no pixel does."""
    visible = setup.mask
    points = setup.gbuffer.position[visible].astype(np.float64)
    origins, dirs, sees = shape_view(setup, index)
    if not sees.any():
        return None
    box = shape.bbox()
    centre = 0.5 * (np.array(box.min, np.float64) + np.array(box.max, np.float64))
    probe = np.array(setup.probe_at, np.float64) if setup.probe_at is not None else centre
    mask = visible_subset(visible, sees)
    return SeenShape(index, mask, origins[sees], dirs[sees], points[sees], centre, probe)


def shape_radiance(
    setup: AuditSetup, app: Applicability, fmt: int, seen: SeenShape, lobe_samples: int
) -> tuple[PooledPasses, SurfaceLobes]:
    """The path-traced radiance along the camera rays of ``seen`` (pooled passes through the pass cache,
    key format ``fmt``) and the BSDF lobes at their first hits (`surface_lobes`, ``lobe_samples`` BSDF
    samples a pixel)."""
    mi, scene = setup.mi, setup.scene
    index, origins, dirs = seen.index, seen.origins, seen.dirs
    pooled = pooled_passes(
        setup,
        {"format": fmt, "quantity": "shape-radiance", "shape": index, "rays": array_digest(dirs)},
        lambda spp, seed: ray_radiance_pass(mi, scene, origins, dirs, spp, seed),
        (-1, 3),
        f"shape{index}: {app.part}",
    )
    lobes = surface_lobes(mi, scene, origins, dirs, lobe_samples, sub_seed(setup.seed, "lobes", index))
    return pooled, lobes


def unit_cube_texels(resolution: int) -> np.ndarray:
    """The unit directions (6N², 3) of a ``resolution``² cube map's texel centres."""
    p = cube_texels(resolution)["point"]
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def probe_capture(
    setup: AuditSetup, fmt: int, index: int, shape, probe: np.ndarray, resolution: int, label: str
) -> PooledPasses:
    """A cube-map probe at ``probe`` (3,): the path-traced radiance along its texel directions
    (`unit_cube_texels` of ``resolution``), through ``shape``, the scene's shape ``index`` (the probe is
    captured without the reflector it serves), pooled through the pass cache (key format ``fmt``; seeds
    labelled ``probe``)."""
    mi, scene = setup.mi, setup.scene
    texels = unit_cube_texels(resolution)
    return pooled_passes(
        setup,
        {
            "format": fmt,
            "quantity": "probe-radiance",
            "shape": index,
            "probe": [float(c) for c in probe],
            "resolution": resolution,
        },
        lambda spp, seed: ray_radiance_pass(mi, scene, probe, texels, spp, seed, skip=shape),
        (-1, 3),
        label,
        seed_label="probe",
    )
