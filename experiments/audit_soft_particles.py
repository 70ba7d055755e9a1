"""The ``soft-particles`` family in `rtfit audit`: a medium-filled convex shape of the user's scene, where
opaque geometry cuts it, against the soft-particle fades.

A **particle** is a shape bounding a homogeneous medium (Mitsuba XML: a ``sphere``, a ``cube`` under any
affine ``to_world`` or a convex mesh (`XmlShape.convex`; its billboards are those of the sphere of its volume
at its centroid and it has no exact row) with an ``interior`` ``homogeneous`` medium and, usually, a ``null``
or thin BSDF; rtfit TOML: a ``homogeneous`` medium of ``[[media]]``, its ``sphere`` or ``cube`` boundary).
An engine draws it as a billboard and fades it with the depth buffer; the family (docs/soft-particles.md)
asks how far each fade is from the exact clipped Beer–Lambert opacity. One case per particle,
``particle<i>``, on the pixels whose camera ray meets the shape:

* **reference**: the opacity 1 − T_c (per RGB channel, no unit) of the medium along the pixel-centre ray from
  the camera, clipped by the first opaque surface behind it, path-traced by Mitsuba's free-flight sampling
  of the scene's own medium along the segment Mitsuba's intersections give (`rtfit.reference.particle_media`:
  the chord through the shape, the opaque depth t_s of the first surface that is not the particle or a
  ``null`` shape — a medium's boundary is not a surface), in independent passes through the cache;
* **billboard rows** (`rtfit.realtime.soft_particles.METHODS`: ``linear``, ``box``, ``box-beer``,
  ``box-beer-ray``, ``spherical``, ``spherical-ray``, ``fitted``) in the camera's view space (z along the
  camera's axis): the billboard at the view depth z of the shape's centre, Δ = t_s·cos θ − z, q the lateral
  distance of the ray's point on the billboard plane, r the particle's radius — the radius of the sphere
  (half-size of the cube) of the shape's volume, r = |det A|^(1/3) for the unit shape's ``to_world`` A —
  α_c = 1 − exp(−2σ_c·r) and the texture α at q (the experiment's own `billboard_inputs`: a sphere's chord
  opacity, a box's α_c on its square); the fade distances s (and the fitted fade's b, p) are fitted to the
  scene by the engine;
* **exact row** of the shape's kind (``exact-sphere`` for a sphere, ``exact-box`` for a cube: any
  parallelepiped), evaluated in the shape's own frame, where the shape is the unit sphere or the cube
  [−1, 1]³: the ray from A⁻¹(o − b) along u = A⁻¹d̂/s, s = |A⁻¹d̂|, the surface at t_s·s, σ_c/s — the table's
  kernel, whose chord in that frame is s times the world chord; the self-check puts it at the reference's
  noise.

Mitsuba's analytic ``sphere`` ignores a non-uniform scale in its ``to_world`` (it warns, and intersects the
sphere of centre b and radius |A·x̂|, measured: a ``scale`` (1, 0.5, 0.8) sphere is hit where the unit sphere
is), so the audit takes that sphere too; an ellipsoid needs a mesh, which is not a particle here (no exact
chord). A particle that no visible opaque surface cuts still applies: its case compares the unclipped opacity
and says so in its notes (the fades are then not exercised).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from rtfit.realtime.soft_particles import BIG, METHODS
from rtfit.reference.build import load_dict, mitsuba_scene_dict
from rtfit.reference.cache import array_digest
from rtfit.reference.particle_media import (
    inside_convex_mesh,
    medium_extinction,
    mesh_volume,
    opacity_pass,
    particle_segments,
    shapes_scene,
)
from rtfit.reference.transforms import rotation_matrix
from rtfit.scenes import Scene

from .audit import Applicability, AuditError, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_setup import AuditSetup, PooledPasses, pooled_passes
from .particle_geometry import CUT_SCENES, billboard_inputs
from .shipped import Sizes

__all__ = ["FAMILY", "SCENES", "Particle"]

FORMAT = 1
_EXACT = {"sphere": "exact-sphere", "box": "exact-box"}

_sizes = Sizes(full=(64, 64, 16384), quick=(20, 20, 1024))
SCENES = tuple(
    _sizes.scene(
        f"soft_particles_{c.shape}.xml",
        f"{c.shape} of absorbing medium, α_c = {c.alpha_c:g} (σ = {c.sigma:.4g}), cut by an opaque plane "
        f"tilted {c.tilt_deg:g}°" + (", the camera inside it" if c.inside else ""),
        defines=c.defines(),
        name=c.name,
        quick=c.quick,
    )
    for c in CUT_SCENES
)
"""The scenes ``rtfit run soft-particles`` audits (scenes/library/soft_particles_{sphere,box}.xml, one file
per shape, its ``<default>`` parameters set per case by `particle_geometry.CUT_SCENES`): the canned cases of
the experiment before the engine, at its sizes and samples (20×20 at 1024 spp quick, 64×64 at 16384 full)."""


@dataclass(frozen=True)
class Particle:
    """One particle of the scene: ``kind`` (``sphere``, ``box`` or ``mesh``), ``to_world`` (4×4: the unit
    sphere or the cube [−1, 1]³ → world; for a convex mesh the sphere of its volume at its centroid), the
    Mitsuba ``medium``, ``scene`` (the particle's shape alone, for ray queries), ``opaque`` (a scene of the
    opaque shapes, or None) and a mesh's ``mesh`` (vertices, faces)."""

    kind: str
    to_world: np.ndarray
    medium: Any
    scene: Any
    opaque: Any
    mesh: tuple[np.ndarray, np.ndarray] | None = None

    def contains(self, point) -> bool:
        """True when ``point`` (the camera) lies inside the shape."""
        if self.mesh is not None:
            return inside_convex_mesh(*self.mesh, point)
        local = np.linalg.solve(self.linear, np.asarray(point, np.float64) - self.centre)
        return bool(np.linalg.norm(local, np.inf if self.kind == "box" else 2) < 1.0)

    @property
    def linear(self) -> np.ndarray:
        return self.to_world[:3, :3]

    @property
    def centre(self) -> np.ndarray:
        return self.to_world[:3, 3]

    @property
    def radius(self) -> float:
        """r = |det A|^(1/3): the radius of the sphere (half-size of the cube) of the shape's volume."""
        return abs(float(np.linalg.det(self.linear))) ** (1.0 / 3.0)


def _affine(linear, offset) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = linear
    m[:3, 3] = offset
    return m


def box_to_world(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray | None:
    """The 4×4 map of the cube [−1, 1]³ onto a mesh that is a parallelepiped (Mitsuba's ``cube`` under an
    affine ``to_world``: its faces fall in 6 planes of 3 opposite pairs), or None: the centre b is the mean
    of the 6 face centroids, the columns the centroids of three non-opposite faces minus b."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    groups: list[tuple[np.ndarray, set]] = []
    for k, nk in enumerate(n):
        for g, idx in groups:
            if float(g @ nk) > 1.0 - 1e-6:
                idx.update(f[k].tolist())
                break
        else:
            groups.append((nk, set(f[k].tolist())))
    if len(groups) != 6:
        return None
    centres = [v[sorted(idx)].mean(axis=0) for _, idx in groups]
    b = np.mean(centres, axis=0)
    cols: list[np.ndarray] = []
    used: list[np.ndarray] = []
    for (g, _), c in zip(groups, centres, strict=True):
        if all(float(g @ u) > -1.0 + 1e-6 for u in used):
            used.append(g)
            cols.append(c - b)
    if len(cols) != 3:
        return None
    return _affine(np.stack(cols, axis=1), b)


def _is_null(mi, shape) -> bool:
    bsdf = shape.bsdf()
    return bsdf is not None and mi.has_flag(bsdf.flags(), mi.BSDFFlags.Null)


def _xml_particle(setup: AuditSetup, source: int, label: str) -> Particle:
    mi = setup.mi
    xml = setup.info.xml
    spec = xml.shapes[source]
    loaded = list(setup.scene.shapes())
    boundaries = [k for k, s in enumerate(loaded) if s.interior_medium() is not None]
    order = [i for i, s in enumerate(xml.shapes) if s.interior].index(source)
    by_id = [k for k in boundaries if spec.id and loaded[k].id() == spec.id]
    if by_id:
        index = by_id[0]
    elif order < len(boundaries):
        index = boundaries[order]
    else:
        raise AuditError(f"soft-particles: {label}: Mitsuba did not instantiate it")
    shape = loaded[index]
    opaque = [s for k, s in enumerate(loaded) if k != index and not _is_null(mi, s)]
    opaque_scene = shapes_scene(mi, opaque) if opaque else None
    if spec.type not in ("sphere", "cube"):  # a convex mesh (`XmlShape.convex`): no exact chord
        mesh = (
            np.asarray(shape.vertex_positions_buffer(), np.float64).reshape(-1, 3),
            np.asarray(shape.faces_buffer(), np.int64).reshape(-1, 3),
        )
        volume, centroid = mesh_volume(*mesh)
        r = (3.0 * volume / (4.0 * math.pi)) ** (1.0 / 3.0)
        return Particle("mesh", _affine(np.eye(3) * r, centroid), shape.interior_medium(),
                        shapes_scene(mi, [shape]), opaque_scene, mesh)  # fmt: skip
    if spec.type == "sphere":  # as Mitsuba intersects it: centre b, radius |A·x̂| (no ellipsoid, see below)
        m = np.asarray(mi.traverse(shape)["to_world"].matrix, np.float64).reshape(4, 4)
        to_world = _affine(np.eye(3) * float(np.linalg.norm(m[:3, 0])), m[:3, 3])
        kind = "sphere"
    else:
        to_world = box_to_world(
            np.asarray(shape.vertex_positions_buffer(), np.float64).reshape(-1, 3),
            np.asarray(shape.faces_buffer(), np.int64).reshape(-1, 3),
        )
        if to_world is None:
            raise AuditError(f"soft-particles: {label}: the cube is not a parallelepiped")
        kind = "box"
    return Particle(kind, to_world, shape.interior_medium(), shapes_scene(mi, [shape]), opaque_scene)


def _toml_particle(setup: AuditSetup, source: int, label: str) -> Particle:
    mi = setup.mi
    scene = setup.source
    medium = scene.media[source]
    alone = load_dict(
        mi, mitsuba_scene_dict(mi, Scene(name=scene.name, camera=scene.camera, media=(medium,)))
    )
    shapes = [s for s in alone.shapes() if s.interior_medium() is not None]
    if len(shapes) != 1:
        raise AuditError(f"soft-particles: {label}: its boundary did not load as one shape")
    bnd = medium.boundary
    if bnd.kind == "sphere":
        kind, to_world = "sphere", _affine(np.eye(3) * bnd.radius, bnd.center)
    else:
        rot = rotation_matrix(bnd.rotate_axis, bnd.rotate_deg)
        kind, to_world = "box", _affine(rot @ np.diag(np.asarray(bnd.size, np.float64) / 2), bnd.center)
    has_opaque = bool(list(setup.scene.shapes())) if setup.scene is not None else False
    return Particle(
        kind,
        to_world,
        shapes[0].interior_medium(),
        shapes_scene(mi, shapes),
        setup.scene if has_opaque else None,
    )


def scene_particle(setup: AuditSetup, app: Applicability) -> Particle:
    """The `Particle` of ``app`` (its source: an index into `XmlScene.shapes` or `Scene.media`)."""
    if app.source is None:
        raise AuditError(f"soft-particles: {app.part} is not a medium of the scene")
    if setup.info.xml is not None:
        return _xml_particle(setup, app.source, app.part)
    if setup.info.format == "rtfit-toml" and setup.source is not None:
        return _toml_particle(setup, app.source, app.part)
    raise AuditError(f"soft-particles: {setup.info.format} scenes hold no particle")


def _camera(setup: AuditSetup) -> tuple[np.ndarray, np.ndarray]:
    """(camera position (3,), view frame (3, 3): columns x, y, and the viewing axis z) of the run's sensor."""
    m = np.asarray(setup.sensor.world_transform().matrix, np.float64).reshape(4, 4)
    frame = m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0, keepdims=True)
    return m[:3, 3].copy(), frame


def _exact_inputs(p: Particle, origin, dirs, t_s, sigma: float) -> dict:
    """The exact kernels' inputs in the shape's own frame (module docstring): the chord there is s times the
    world chord, so σ/s gives the world optical depth."""
    inv = np.linalg.inv(p.linear)
    local = dirs @ inv.T
    s = np.linalg.norm(local, axis=1)
    u = local / s[:, None]
    c = -(inv @ (np.asarray(origin, np.float64) - p.centre))
    n = len(dirs)
    return {
        "dx": u[:, 0], "dy": u[:, 1], "dz": u[:, 2],
        "cx": np.full(n, c[0]), "cy": np.full(n, c[1]), "cz": np.full(n, c[2]),
        "t_surface": np.where(np.isfinite(t_s), t_s * s, BIG),
        "radius": np.ones(n),
        "sigma": sigma / s,
    }  # fmt: skip


def bernoulli_floor(pooled: PooledPasses, length: np.ndarray) -> PooledPasses:
    """The passes with each standard error at least that of a Bernoulli mean at the continuity-corrected
    p̃ = (k + ½)/(N + 1) (k collisions in N samples): √(p̃(1 − p̃)/N). Every sample is 0 or 1, so the pooled
    sample variance is N/(N − 1)·p̂(1 − p̂) — zero where all N samples agree (a dense particle: all of 64
    samples collide with probability 0.98^64 = 0.27 at 1 − T = 0.98), which would make any difference from
    the reference look infinitely significant. A zero-length segment stays exact (opacity 0, error 0)."""
    n = pooled.spp
    p = (pooled.mean * n + 0.5) / (n + 1)
    floor = np.sqrt(p * (1.0 - p) / n) * (np.asarray(length)[:, None] > 0.0)
    return replace(pooled, stderr=np.maximum(pooled.stderr, floor))


def particle_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """The ``particle<i>`` case of ``app`` (module docstring)."""
    p = scene_particle(setup, app)
    mi = setup.mi
    origin, frame = _camera(setup)
    shape_hw = setup.gbuffer.view_dir.shape[:2]
    dirs_all = setup.gbuffer.view_dir.reshape(-1, 3).astype(np.float64)
    dirs_all /= np.maximum(np.linalg.norm(dirs_all, axis=1, keepdims=True), 1e-30)
    inside = p.contains(origin)
    t_in, t_out, t_s = particle_segments(mi, p.scene, p.opaque, origin, dirs_all, inside)
    hit = np.isfinite(t_in)
    if not hit.any():
        raise AuditError(f"soft-particles: {app.part}: no pixel-centre ray of the camera meets it")
    mask = hit.reshape(shape_hw)
    d, t_in, t_out, t_s = dirs_all[hit], t_in[hit], t_out[hit], t_s[hit]
    length = np.maximum(np.minimum(t_out, t_s) - t_in, 0.0)
    tag = f"particle{app.source}"
    what = {"format": FORMAT, "quantity": "particle-opacity", "particle": app.source,
            "rays": array_digest(origin, d, t_in, length)}  # fmt: skip

    def render(spp: int, seed: int):
        return opacity_pass(mi, p.medium, origin, d, t_in, length, spp, seed)

    pooled = bernoulli_floor(pooled_passes(setup, what, render, (-1, 3), f"{tag}: {app.part}"), length)
    sigma = medium_extinction(mi, p.medium, p.centre)
    r = p.radius
    view = d @ frame  # view-space rays: camera at the origin, +z its axis
    centre_view = frame.T @ (p.centre - origin)
    t_view = np.where(np.isfinite(t_s), t_s, BIG)
    billboard = "box" if p.kind == "box" else "sphere"
    inputs = []
    for c in range(3):
        alpha_c = -math.expm1(-2.0 * float(sigma[c]) * r)
        row = billboard_inputs(view, centre_view, r, alpha_c, billboard, t_view)
        inputs.append({**row, **_exact_inputs(p, origin, d, t_s, float(sigma[c]))})
    exact = _EXACT.get(p.kind)  # (a mesh has no exact chord kernel: no exact row, no self-check)
    others = set(_EXACT.values()) - {exact}
    methods = {mid: METHODS[mid] for mid in app.methods if mid in METHODS and mid not in others}
    cut = int(np.sum((t_s > t_in) & (t_s < t_out)))
    blocked = int(np.sum(t_s <= t_in))
    notes = [
        f"{p.kind} of volume radius r = {r:.4g}, σ_t = ({', '.join(f'{v:.4g}' for v in sigma)}) per unit: "
        f"α_c = {', '.join(f'{-math.expm1(-2 * v * r):.3f}' for v in sigma)}; {int(hit.sum())} pixels meet "
        f"it, {cut} with opaque geometry inside it, {blocked} with opaque geometry in front of it",
    ]
    if inside:
        notes.append("the camera is inside the particle: its chords start at the camera")
    if exact is None:
        notes.append(
            "a convex mesh: billboards of the sphere of its volume at its centroid; no exact row (the "
            "table's exact kernels are the sphere's and the box's chords), so no self-check"
        )
    if cut == 0:
        notes.append(
            "no visible pixel has opaque geometry inside the volume: the depth fades are not exercised "
            "(every row compares the unclipped opacity)"
        )
    ref = pooled.reference(
        mask,
        quantity="opacity 1 − T of the particle's medium along the pixel ray, clipped by the opaque "
        "surface (1)",
        integrator="free-flight sampling of the medium (Mitsuba Medium.sample_interaction)",
        integrator_reason=(
            "homogeneous medium in a convex shape: the chord and the opaque depth from Mitsuba's "
            "intersections, each sample Bernoulli(1 − T) per channel"
        ),
    )
    return [
        FamilyCase(
            id=tag,
            label=f"{app.part}: particle opacity",
            reference=ref,
            channel_inputs=tuple(inputs),
            parameters={
                "particle": app.part,
                "shape": p.kind,
                "radius": r,
                "sigma_t": [float(v) for v in sigma],
                "pixels": int(hit.sum()),
                "cut_pixels": cut,
                "blocked_pixels": blocked,
            },
            units="1",
            notes=tuple(notes),
            methods=methods,
        )
    ]


FAMILY = AuditFamily(
    name="soft-particles",
    quantity="particle_opacity",
    cases=particle_cases,
    describe=(
        "Per medium-filled convex shape (a homogeneous medium in a sphere or a cube): the opacity 1 − T of "
        "its medium along each pixel-centre ray that meets it, clipped by the first opaque surface behind it "
        "(medium boundaries are not surfaces), path-traced by Mitsuba's free-flight sampling of the scene's "
        "own medium along the chord Mitsuba's intersections give. The billboard fades read the camera's view "
        "depth of the shape's centre, the depth buffer and the radius of the shape's volume; their fade "
        "distances are fitted to the scene. The exact row of the shape's kind is the clipped Beer–Lambert "
        "chord in the shape's own frame."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "soft-particles",
            "particle opacity",
            ("particle", "surface"),
            "{part} is a particle volume the camera sees; where opaque geometry cuts it, a soft-particle "
            "fade replaces its clipped opacity",
            "the opacity 1 − T of its medium along the pixel rays, clipped by the first opaque surface",
            "free-flight sampling of the medium along the chord Mitsuba's intersections give (medium "
            "boundaries are not surfaces)",
        ),
    ),
)
