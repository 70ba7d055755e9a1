r"""The ``parallax-occlusion`` family in `rtfit audit`: parallax occlusion mapping on a bump-mapped shape.

A shape whose BSDF is a ``bumpmap`` of a ``bitmap`` texture (directly or inside a ``twosided``; in a Mitsuba
XML scene, or in an rtfit TOML scene's ``mitsuba_xml`` shape that keeps its file's BSDFs; the rule's
``height-field`` part, `rtfit.experiments.families.RULES`) carries a height field h(u, v): what the bump map
differentiates for its normals, an engine marches with parallax occlusion mapping (POM) on the flat shape
instead of displacing the mesh. One case per such shape:

* **the height field**: the texture's texels as Mitsuba holds them (`texture_texels`), looked up by the
  family's kernel text (`rtfit.realtime.parallax_occlusion.HeightMap`: bilinear or nearest, wrap repeat,
  clamp or mirror). Mitsuba's bindings do not say which filter and wrap mode a bitmap has, so they are
  *identified*: the one `HeightMap` whose values match Mitsuba's own ``eval_1`` at 4,096 points over
  [−1.5, 2.5]² of the shape's UV (within 10⁻⁴) is used; none matching is a one-line error. The texture's
  ``to_uv`` (t = A·uv + b) is applied to the pixels' coordinates and tangents.
* **the height range** ``--pom-depth`` s (texture units: one texture tile is 1 wide; default
  `POM_DEPTH_DEFAULT`, the family's own default `DEPTH_METHODS` ``scale``; `POM_DEPTH_RANGE`): h = 1 is the
  shape's surface, h = 0 lies s·L deep, L = the median √|∂p/∂t_u × ∂p/∂t_v| over the shape's pixels (scene
  units per texture unit).
* **the pixels**: those whose pixel-centre ray first hits this shape (`pixel_surface`), on its camera-facing
  side (the side most of its pixels see; the height field is carved into that side).
* **the per-pixel inputs**: (u₀, v₀) the texture coordinates of the hit; the view vector in the texture's
  tangent frame: with w the unit vector to the eye, T_u = ∂p/∂t_u, T_v = ∂p/∂t_v and n the shading normal
  towards the camera, w = α·T_u + β·T_v + γ·n (least squares in (α, β), γ = w·n) and V = (α·L, β·L, γ)/‖·‖:
  then s·V_xy/V_z = s·L·(α, β)/γ, exactly the texture offset of one height range of depth along the ray on a
  flat, affinely mapped shape (on a conformal map V is the usual unit tangent-space vector). Pixels with
  γ ≤ 10⁻³ (grazing, or the shape's silhouette) are left out.
* **the reference**: the shape displaced along its normals by −s·L·(1 − h) (`displaced_shape`, a UV grid of
  `CELLS_PER_TEXEL` cells per texel, at most `MAX_CELLS` per side, heights from Mitsuba's ``eval_1``),
  intersected with the same pixel-centre rays by Mitsuba (``ray_intersect``): the visible point's depth
  below the shape, (p₀ − p_hit)·n/(s·L), as a fraction of the height range — deterministic, noise floor
  zero. The mesh's own error (piecewise-linear over its cells) is measured against a mesh of half as many
  cells per side and reported (the RMS difference; the fine mesh's own error is about a third of it: it
  shrinks with the cell's area); pixels whose ray misses either mesh (through the carved shape's open border)
  are left out.
* **rows** (`DEPTH_METHODS`, the family's ``listing`` and ``stable`` marches with the depth as output, the
  height field and s as their fixed keywords): ``pom-listing`` and ``pom-stable`` with the family's sample
  range (n 8 … 40), and the stable march at n 4 … 16 and 16 … 64 (``pom-stable-n4-16``,
  ``pom-stable-n16-64``): error and cost against the sample budget. mip 0 (full POM: the LOD blend is not
  audited). A user's ``@approximation(quantity="parallax_depth")`` reads the same (u₀, v₀) and view vector,
  with the height field as ``g.field(ops, u, v)`` and the range as ``g.scale`` (`on_field`, as the rows).

**The soft self-shadow** (``METHODS``' third output), one more case per area light of the scene (an
emitter shape other than the bumped one; none: a note says the shadow is not audited), quantity
``parallax_shadow``, on the depth case's pixels whose light vector to the light's centre (bounding-box
centre) has L_z > `MIN_COS` in the same tangent frame (V's construction applied to it) and whose visible
point sees some of the light:

* **the reference**: at the displaced mesh's first hit (its normal towards the camera's side), the fraction
  V = E_occluded/E_unoccluded of the light's irradiance that reaches it past the displaced mesh (Mitsuba's
  own light sampling, ``emitter.sample_direction``, ``--spp`` samples per pixel, ``ray_test`` against the
  displaced mesh alone: the height field's own shadow, what the shadow query models; other occluders are a
  shadow map's), with its delta-method standard error (`emitter_visibility`);
* **rows** (`SHADOW_AUDIT_METHODS`): the pixel shader's shadow (``pom-listing-shadow``,
  ``pom-stable-shadow``: the march n 8…40, then the 7-sample shadow at the marched (u, v)), the shadow
  model alone at the exact visible point's texture coordinates (``listing-shadow``, ``stable-shadow``:
  inputs ``u``, ``v`` from the hit's barycentric coordinates, `displaced_hits`), each with (softening,
  floor) declared and fitted, and POM without the shadow query (``pom-no-shadow``: 1).

`SCENES`: the bump-mapped floor ``rtfit run parallax-occlusion`` audits (scenes/library/
parallax_occlusion_floor.xml, three views, two depths, one square area light at 70°). A ``normalmap`` stores
normals, not heights: `rtfit audit --list` names such a shape as not applying.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import math
import time

import numpy as np

from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.methods import Method
from rtfit.realtime.parallax_occlusion import DEPTH_METHODS, SHADOW_AUDIT_METHODS, WRAP_MODES, HeightMap
from rtfit.reference.estimators import is_pass_through
from rtfit.reference.parallax_occlusion import (
    bump_texture,
    displaced_hits,
    displaced_shape,
    emitter_visibility,
    exact_hits,
    height_field_shapes,
    pixel_surface,
    texture_texels,
    texture_values,
    uv_range,
)

from .audit import Applicability, AuditError, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_setup import AuditReference, AuditSetup
from .case_inputs import masked_image
from .shipped import ShippedScene, Sizes

__all__ = [
    "CELLS_PER_TEXEL",
    "FAMILY",
    "MAX_CELLS",
    "POM_DEPTH_DEFAULT",
    "POM_DEPTH_RANGE",
    "SCENES",
    "VIEWS",
    "check_pom_depth",
    "height_map_of",
    "on_field",
    "parallax_cases",
    "tangent_view",
]

POM_DEPTH_DEFAULT = float(DEPTH_METHODS["pom-stable"].fixed["scale"])
"""``--pom-depth`` when not given: the family's own default height range (0.1 texture units)."""
POM_DEPTH_RANGE = (0.001, 1.0)
"""``--pom-depth`` bounds (texture units): a range of 1 is a valley as deep as the tile is wide."""
CELLS_PER_TEXEL = 8
"""Cells of the displaced mesh per texel along each UV axis (the cells lie inside the texels' bilinear
patches; the mesh's own error, the patches' twist, ∝ (⅛ texel)²)."""
MIN_CELLS, MAX_CELLS = 16, 1024
"""Cells per side of the displaced mesh's UV grid: at least, at most (2·1024² triangles)."""
MIN_COS = 1e-3
"""Pixels whose view vector makes γ = w·n below this with the shape's normal are left out."""
SHADOW_OFFSET = 1e-3
"""The shadow rays start this fraction of the height range (scene units) off the displaced mesh, along its
normal."""
_PROBES = 4096
_MATCH = 1e-4


def check_pom_depth(value) -> float:
    """``--pom-depth`` as a float in `POM_DEPTH_RANGE` (None: `POM_DEPTH_DEFAULT`), or `AuditError` (one
    line, before anything is read or rendered)."""
    if value is None:
        return POM_DEPTH_DEFAULT
    lo, hi = POM_DEPTH_RANGE
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    if not (lo <= v <= hi):
        raise AuditError(
            f"--pom-depth {value!r}: expected the height map's range in texture units, {lo:g} … {hi:g} "
            f"(default {POM_DEPTH_DEFAULT:g})"
        )
    return v


def _to_uv(mi, texture) -> tuple[np.ndarray, np.ndarray]:
    """(A (2, 2), b (2,)) of the texture's ``to_uv``: texture coordinates t = A·uv + b."""
    params = mi.traverse(texture)
    m = np.array(params["to_uv"].matrix, np.float64).reshape(3, 3) if "to_uv" in params else np.eye(3)
    return m[:2, :2], m[:2, 2]


def height_map_of(mi, texture) -> tuple[HeightMap, str]:
    """The `HeightMap` of a bitmap ``texture`` whose lookup matches Mitsuba's ``eval_1`` (module docstring),
    and its description; `AuditError` where none does."""
    try:
        texels = texture_texels(mi, texture)
    except ValueError as e:
        raise AuditError(f"parallax-occlusion: {e}") from None
    a, b = _to_uv(mi, texture)
    rng = np.random.default_rng(0)
    uv = rng.uniform(-1.5, 2.5, (_PROBES, 2))
    want = texture_values(mi, texture, uv[:, 0], uv[:, 1])
    t = uv.astype(np.float32).astype(np.float64) @ a.T + b
    for nearest in (False, True):
        for wrap in WRAP_MODES:
            hm = HeightMap(texels, wrap, nearest)
            got = hm(NUMPY_OPS, t[:, 0], t[:, 1])
            if np.max(np.abs(got - want)) <= _MATCH * max(1.0, float(np.max(np.abs(texels)))):
                h, w = texels.shape
                return hm, f"{w}×{h} texels, {'nearest' if nearest else 'bilinear'}, wrap {wrap}"
    raise AuditError(
        "parallax-occlusion: the bump map's texture matches none of the lookups the family's kernel text "
        "writes (bilinear or nearest; repeat, clamp or mirror)"
    )


def tangent_view(w: np.ndarray, t_u: np.ndarray, t_v: np.ndarray, n: np.ndarray, length: float):
    """(V (N, 3), γ (N,)): the unit vectors to the eye ``w`` in the texture's tangent frame (module
    docstring), rows (α·L, β·L, γ)/‖·‖ with w ≈ α·T_u + β·T_v + γ·n."""
    g00 = np.einsum("ij,ij->i", t_u, t_u)
    g01 = np.einsum("ij,ij->i", t_u, t_v)
    g11 = np.einsum("ij,ij->i", t_v, t_v)
    r0 = np.einsum("ij,ij->i", w, t_u)
    r1 = np.einsum("ij,ij->i", w, t_v)
    det = g00 * g11 - g01 * g01
    safe = np.where(np.abs(det) > 0, det, 1.0)
    alpha = (g11 * r0 - g01 * r1) / safe
    beta = (g00 * r1 - g01 * r0) / safe
    gamma = np.einsum("ij,ij->i", w, n)
    v = np.stack([alpha * length, beta * length, gamma], axis=1)
    norm = np.linalg.norm(v, axis=1, keepdims=True)
    return v / np.where(norm > 0, norm, 1.0), gamma


def _shape(setup: AuditSetup, app: Applicability):
    """The loaded Mitsuba shape the applicability names (`Part.source`: its index in `XmlScene.shapes`; in an
    rtfit TOML scene, its ordinal among `height_field_shapes`)."""
    if setup.info.format == "rtfit-toml":
        shapes = height_field_shapes(setup.mi, setup.scene.shapes())
        if app.source is None or not 0 <= app.source < len(shapes):
            raise AuditError(f"parallax-occlusion: {app.part} is not a shape of the loaded scene")
        return shapes[app.source]
    xml = setup.info.xml
    if xml is None or app.source is None or not 0 <= app.source < len(xml.shapes):
        raise AuditError(f"parallax-occlusion: {app.part} is not a shape of the loaded scene")
    spec = xml.shapes[app.source]
    loaded = list(setup.scene.shapes())
    by_id = [s for s in loaded if spec.id and s.id() == spec.id]
    if by_id:
        return by_id[0]
    if len(loaded) == len(xml.shapes):
        return loaded[app.source]
    raise AuditError(f"parallax-occlusion: {app.part}: give the shape an id (Mitsuba did not keep its order)")


def _cells(hm: HeightMap, a: np.ndarray, span: tuple[float, float], factor: float) -> tuple[int, int]:
    """Cells per side of the displaced mesh's UV grid: `CELLS_PER_TEXEL` × the texels the shape's UV range
    spans along each axis (× ``factor``), within `MIN_CELLS` … `MAX_CELLS`."""
    h, w = hm.shape
    texels = (span[0] * np.linalg.norm(a[:, 0]) * max(w, h), span[1] * np.linalg.norm(a[:, 1]) * max(w, h))
    return tuple(  # type: ignore[return-value]
        int(np.clip(math.ceil(CELLS_PER_TEXEL * t * factor), MIN_CELLS * factor, MAX_CELLS * factor))
        for t in texels
    )


def parallax_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """The case of one bump-mapped shape (module docstring); none where the camera sees none of it."""
    mi = setup.mi
    depth = check_pom_depth(setup.pom_depth)
    shape = _shape(setup, app)
    texture = bump_texture(mi, shape.bsdf())
    if texture is None:
        raise AuditError(f"parallax-occlusion: {app.part}: the loaded shape has no bumpmap texture")
    hm, lookup = height_map_of(mi, texture)
    a, b = _to_uv(mi, texture)
    t0 = time.perf_counter()
    ps = pixel_surface(mi, setup.scene, setup.sensor, shape)
    on = ps.on_shape & setup.mask.reshape(-1)
    if is_pass_through(mi, shape) or not on.any():
        return []
    w = -ps.dirs
    side = 1.0 if np.sum(np.einsum("ij,ij->i", w[on], ps.n[on])) >= 0.0 else -1.0
    n = side * ps.n
    inv = np.linalg.inv(a)  # ∂p/∂t = [∂p/∂u ∂p/∂v]·A⁻¹
    t_u = ps.dp_du * inv[0, 0] + ps.dp_dv * inv[1, 0]
    t_v = ps.dp_du * inv[0, 1] + ps.dp_dv * inv[1, 1]
    length = float(np.median(np.sqrt(np.linalg.norm(np.cross(t_u[on], t_v[on]), axis=1))))
    view, gamma = tangent_view(w, t_u, t_v, n, length)
    on &= np.isfinite(view).all(axis=1) & (gamma > MIN_COS)
    d_scene = depth * length
    u_lo, u_hi, v_lo, v_hi = uv_range(mi, shape)
    span = (u_hi - u_lo, v_hi - v_lo)
    fine = displaced_shape(mi, shape, texture, d_scene, side, _cells(hm, a, span, 1.0))
    coarse = displaced_shape(mi, shape, texture, d_scene, side, _cells(hm, a, span, 0.5))
    idx = np.flatnonzero(on)
    fine_scene = fine.scene(mi)
    p_hit, n_hit, uv_hit, ok = displaced_hits(mi, fine, fine_scene, ps.origins[idx], ps.dirs[idx])
    p_half, _, ok_half = exact_hits(mi, coarse.scene(mi), ps.origins[idx], ps.dirs[idx])
    keep = ok & ok_half
    missed = int(idx.size - keep.sum())
    idx, p_hit, p_half, n_hit, uv_hit = idx[keep], p_hit[keep], p_half[keep], n_hit[keep], uv_hit[keep]
    if idx.size == 0:
        return []
    ref = np.einsum("ij,ij->i", ps.p[idx] - p_hit, n[idx]) / d_scene
    ref_half = np.einsum("ij,ij->i", ps.p[idx] - p_half, n[idx]) / d_scene
    seconds = time.perf_counter() - t0
    height, width = setup.mask.shape
    mask = np.zeros(height * width, bool)
    mask[idx] = True
    mask = mask.reshape(height, width)
    tex = ps.uv[idx] @ a.T + b
    inputs = {
        "u0": tex[:, 0],
        "v0": tex[:, 1],
        "vx": view[idx, 0],
        "vy": view[idx, 1],
        "vz": view[idx, 2],
    }
    rows = {mid: on_field(m, hm, depth) for mid, m in DEPTH_METHODS.items()}
    mesh_rms = float(np.sqrt(np.mean((ref - ref_half) ** 2)))
    texels = hm.texels
    reference = AuditReference.deterministic(
        mask,
        ref,
        (setup.scene_digest, app.part, depth, fine.cells),
        seconds,
        "the visible point's depth below the shape, a fraction of the height range (1: h = 0)",
        "Mitsuba ray_intersect of the pixel-centre rays with the shape displaced by the height "
        f"field ({fine.cells[0]}×{fine.cells[1]} cells; no sampling, not cached)",
        "first hits are exact: deterministic, noise floor zero; the mesh's own "
        f"(piecewise-linear) error, against a mesh of half the cells: RMS {mesh_rms:.3g}",
    )
    notes = [
        f"height field: the bump map's texture, {lookup} (identified against Mitsuba's eval_1)",
        f"height range --pom-depth {depth:g} texture units = {d_scene:.4g} scene units "
        f"(L = {length:.4g} scene units per texture unit)",
        f"the displaced mesh's own error (fine vs half the cells per side): RMS {mesh_rms:.3g} of the range",
        "mip 0 (full POM: the LOD blend is not audited; its LOD pop: rtfit run parallax-occlusion)",
    ]
    if missed:
        notes.append(f"{missed} pixels of the shape left out: their ray misses the fine or the coarse mesh")
    if texels.min() < 0.0 or texels.max() > 1.0:
        notes.append(
            f"the texels span {texels.min():.3g} … {texels.max():.3g}, outside the march's [0, 1]: the "
            "reference displaces by them as they are"
        )
    flip = np.einsum("ij,ij->i", n_hit, n[idx]) < 0  # the hit's normal towards the camera's side
    n_hit = np.where(flip[:, None], -n_hit, n_hit)
    hit = _Hits(idx, inputs, p_hit, n_hit, uv_hit @ a.T + b, t_u[idx], t_v[idx], n[idx], ps.p[idx], length)
    lights = _area_lights(mi, setup.scene, shape)
    if not lights:
        notes.append("the soft self-shadow is not audited: the scene has no area light")
    shadows = [
        case
        for k, (light_id, emitter, centre) in enumerate(lights)
        for case in _shadow_cases(
            setup, app, k, light_id, emitter, centre, hit, fine_scene, hm, depth, d_scene
        )
    ]
    return [
        FamilyCase(
            id=f"pom-{app.source}",
            label=f"parallax occlusion, {app.part.split(':')[0]}",
            reference=reference,
            channel_inputs=(inputs,),
            parameters={
                "pom_depth": depth,
                "depth_scene": d_scene,
                "texel_length": length,
                "lookup": lookup,
                "side": side,
                "mesh_cells": list(fine.cells),
                "mesh_rms": mesh_rms,
                "pixels": int(idx.size),
                "missed": missed,
            },
            units="1 (fraction of the height range)",
            notes=tuple(notes),
            methods=rows,
            quantity="parallax_depth",
            user_rows=functools.partial(on_field, field=hm, scale=depth),
        ),
        *shadows,
    ]


@dataclasses.dataclass(frozen=True)
class _Hits:
    """The depth case's pixels (``idx``, flat indices; ``inputs``: its per-pixel inputs) and, per pixel, the
    displaced mesh's first hit ``p`` with its normal ``n`` (towards the camera's side), the texture
    coordinates ``tex`` there, the tangents ``t_u``, ``t_v``, the shape's normal ``n0`` and point ``p0``
    under the pixel, and L (``length``)."""

    idx: np.ndarray
    inputs: dict
    p: np.ndarray
    n: np.ndarray
    tex: np.ndarray
    t_u: np.ndarray
    t_v: np.ndarray
    n0: np.ndarray
    p0: np.ndarray
    length: float


def _area_lights(mi, scene, shape) -> list[tuple[str, object, np.ndarray]]:
    """(id, emitter, centre of its shape's bounding box) of each area light of ``scene`` other than
    ``shape``."""
    out = []
    for k, s in enumerate(scene.shapes()):
        if not s.is_emitter() or s == shape:
            continue
        e = s.emitter()
        if not mi.has_flag(e.flags(), mi.EmitterFlags.Surface):
            continue
        out.append((s.id() or f"area light {k}", e, np.array(s.bbox().center(), np.float64).reshape(3)))
    return out


def _shadow_cases(setup, app, k, light_id, emitter, centre, hit, fine_scene, hm, depth, d_scene):
    """The soft self-shadow toward one area light (module docstring): the case over the depth case's pixels
    where the light's centre lies above the shape (L_z > `MIN_COS`) and the visible point sees some of it."""
    mi = setup.mi
    t0 = time.perf_counter()
    w = centre[None, :] - hit.p0
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    light, lz = tangent_view(w, hit.t_u, hit.t_v, hit.n0, hit.length)
    up = np.isfinite(light).all(axis=1) & (lz > MIN_COS)
    seed = int.from_bytes(
        hashlib.sha256(f"{setup.seed}:{app.part}:{light_id}".encode()).digest()[:4], "little"
    )
    lv = emitter_visibility(mi, emitter, fine_scene, hit.p[up], hit.n[up], setup.spp, seed=seed,
                            offset=SHADOW_OFFSET * d_scene)  # fmt: skip
    sel = np.flatnonzero(up)[lv.e_unoccluded > 0]
    keep = lv.e_unoccluded > 0
    if sel.size == 0:
        return []
    seconds = time.perf_counter() - t0
    height, width = setup.mask.shape
    mask = np.zeros(height * width, bool)
    mask[hit.idx[sel]] = True
    mask = mask.reshape(height, width)
    inputs = {
        **{n: v[sel] for n, v in hit.inputs.items()},
        "lx": light[sel, 0],
        "ly": light[sel, 1],
        "lz": light[sel, 2],
        "u": hit.tex[sel, 0],
        "v": hit.tex[sel, 1],
    }
    vis, err = lv.visibility[keep], lv.visibility_stderr[keep]
    key = hashlib.sha256(repr((setup.scene_digest, app.part, light_id, depth, setup.spp, seed)).encode())
    reference = AuditReference(
        mean=masked_image(mask, vis),
        stderr=masked_image(mask, err),
        spp=setup.spp,
        passes=1,
        passes_rendered=1,
        cache_key=key.hexdigest()[:16],
        cache_path="",
        seconds=seconds,
        quantity="the fraction of the area light's irradiance at the visible point that the height field "
        "lets through, E_occluded/E_unoccluded",
        integrator="Mitsuba's light sampling (emitter.sample_direction) from the displaced mesh's first hit, "
        "ray_test against the displaced mesh only (no sampling of the camera ray; not cached)",
        integrator_reason="the height field's own shadow, what POM's shadow query models: other occluders "
        "are a shadow map's; standard error by the delta method on the paired samples",
        mask=mask,
    )
    rows = {mid: on_field(m, hm, depth) for mid, m in SHADOW_AUDIT_METHODS.items()}
    label = f"parallax occlusion soft shadow, {app.part.split(':')[0]}, {light_id}"
    return [
        FamilyCase(
            id=f"pom-{app.source}-shadow-{k}",
            label=label,
            reference=reference,
            channel_inputs=(inputs,),
            parameters={
                "pom_depth": depth,
                "light": light_id,
                "light_centre": [float(c) for c in centre],
                "light_samples": setup.spp,
                "mean_visibility": float(np.mean(vis)),
                "mean_stderr": float(np.mean(err)),
                "pixels": int(sel.size),
            },
            units="1 (fraction of the light's irradiance)",
            notes=(
                f"{light_id}: light vector to its centre {tuple(round(float(c), 4) for c in centre)}; "
                f"{setup.spp} light samples per pixel, mean visibility {np.mean(vis):.3g} "
                f"(mean standard error {np.mean(err):.2g})",
            ),
            methods=rows,
            quantity="parallax_shadow",
            user_rows=functools.partial(on_field, field=hm, scale=depth),
            uncosted={
                "pom-no-shadow": "POM without the shadow query returns the constant 1: no work to time"
            },
        )
    ]


def on_field(method: Method, field: HeightMap, scale: float) -> Method:
    """``method`` (a row of `DEPTH_METHODS`, or a user's approximation of ``parallax_depth``, whose ``g``
    carries them) with the scene's height field and range as fixed keywords: constants of the case."""
    return dataclasses.replace(
        method,
        inputs=tuple(i for i in method.inputs if i.name not in ("field", "scale")),
        fixed={**method.fixed, "field": field, "scale": scale},
    )


FAMILY = AuditFamily(
    name="parallax-occlusion",
    quantity="parallax_depth",
    cases=parallax_cases,
    describe=(
        "A shape whose BSDF is a bumpmap of a bitmap texture: the texture as a height field, carved "
        "--pom-depth texture units into the shape. Reference: the shape displaced along its normals by that "
        "height "
        "field, intersected with the pixel-centre rays by Mitsuba (exact first hits, noise floor zero); the "
        "compared quantity is the visible point's depth below the shape as a fraction of the height range. "
        "Rows: the family's listing and stable marches on the flat shape (the texture looked up as Mitsuba "
        "does, the view vector in the texture's tangent frame), the stable march at three sample ranges. "
        "Toward each area light of the scene, the soft self-shadow: the fraction of the light's irradiance "
        "that reaches the displaced mesh's visible point past the displaced mesh (Mitsuba's light samples, "
        "with standard errors) against the POM shadow query after the march and at the exact visible point, "
        "declared and fitted (softening, floor), and no shadow."
    ),
    quantities=("parallax_shadow",),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "parallax-occlusion",
            "height field",
            ("height-field",),
            "{part}: parallax occlusion mapping marches it on the flat shape instead of displacing the mesh",
            "the visible point's depth below the shape along each pixel-centre ray, on the shape displaced "
            "along its normals by the height field (range --pom-depth texture units); toward each area "
            "light, the fraction of its irradiance the displaced height field lets through to that point",
            "none: Mitsuba ray_intersect of the pixel-centre rays with the displaced mesh (exact first hits, "
            "deterministic: noise floor zero); the shadow: Mitsuba's light samples, ray_test against the "
            "displaced mesh (--spp per pixel)",
        ),
    ),
)


VIEWS = {"overhead": "0, -0.532, 1.462", "45deg": "0, -1.1, 1.1", "grazing": "0, -1.462, 0.532"}
"""The shipped scenes' cameras (scenes/library/parallax_occlusion_floor.xml ``origin``; scene units), 1.556
from the floor's centre and looking at it: 20°, 45° and 70° from the floor's normal."""
DEPTHS = (0.1, 0.15)
"""The shipped scenes' ``pom_depth`` (texture units): the family's default and the old experiment's s."""


_sizes = Sizes(full=(64, 64, 1024), quick=(24, 24, 256))


def _scene(view: str, depth: float) -> ShippedScene:
    return _sizes.scene(
        "parallax_occlusion_floor.xml",
        f"egg-crate height texture (32×32 texels) on a 1×1 floor seen {view}, carved {depth:g} texture units",
        options={"pom_depth": depth},
        defines={"origin": VIEWS[view]},
        name=f"{view}-d{depth:g}".replace(".", "p"),
        quick=view == "45deg" and depth == 0.15,
    )


SCENES = tuple(_scene(v, d) for d in DEPTHS for v in VIEWS)
"""The scenes ``rtfit run parallax-occlusion`` audits (one per view and depth; ``--quick``: 45°, s = 0.15):
the depth reference is deterministic (exact first hits on the displaced mesh); ``spp`` is the light samples
per pixel of the soft shadow's reference (the old experiment's 256 with ``--quick``)."""
