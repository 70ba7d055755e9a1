r"""Light cones in fog: the seed's pseudo-volumetric shell of a spot light, and the light cone's chord.

The seed's model (000:1026-1044, ch. 3 "Foggy lights in the street")
--------------------------------------------------------------------
Each street lamp's lit fog is a cone *mesh* (apex at the lamp, half-angle θ_c, length L along its axis),
drawn additively with a pixel shader: the view vector in the cone's tangent space gives an edge fade that
goes to zero on the silhouette, and "distance attenuation of a light by a square of the v texture
coordinate"; two scrolled noise fetches modulate it. rtfit writes the shader per shell fragment as

    L_frag = k · |n·ω|^p · v^q,      v = 1 − t/L ∈ [0, 1]

— ω the unit view direction, n the cone's outward normal at the fragment (the tangent-space view vector's
z; |n·ω| → 0 on the silhouette, the fade), t the fragment's distance from the apex along the axis, so the
texture coordinate v is 1 at the lamp and 0 at the cone's far rim (the seed's "square of v" is q = 2).
Free parameters: k (W/m²/sr, overall level), p (fade exponent; the seed's tangent-space fade is p = 1) and
q (attenuation exponent, seed 2). The noise is artistic texture (it has no counterpart in a homogeneous
medium) and is left out. The mesh is the lateral surface, open at the rim.

Two blend set-ups, as data (`METHODS`): ``shell`` draws both faces (culling off): a view ray crossing the
cone from outside adds its entry (front face) and exit (back face) fragments; ``shell-front`` culls back
faces (one fragment from outside, *none* from a camera inside the cone, where only back faces are seen).

The physical quantity: single scattering along the view ray from a spot light of intensity I(θ) (W/sr) in
a homogeneous medium, L = σ_s/(4π)·∫ I(θ(s))·e^(−σ_t(s + r))/r² ds over the part of the ray in the beam.
``chord`` evaluates §1's closed form (`rtfit.realtime.volumetric_lightning` ``inverse-square``, one text)
over the view ray's chord through the cone: K·∫_chord ds/r², a hard-edged cone (I = const inside θ_c)
without extinction, K = σ_s·I/(4π) (W/m/sr). It is what the shell's single fragment cannot know: how long
the ray stays in the beam and how close it passes the lamp.

Geometry (`cone_chord`, one text for all three methods)
-------------------------------------------------------
With w = o − P (camera minus apex), a the unit axis, κ = cos²θ_c, a point o + sω is in the infinite double
cone where F(s) = ((w + sω)·a)² − κ|w + sω|² ≥ 0, a quadratic A s² + 2B s + C with A = (ω·a)² − κ,
B = (ω·a)(w·a) − κ(ω·w), C = (w·a)² − κ|w|². Its roots come from the cancellation-free pair
q = −(B + sgn(B)√(B² − AC)), s = q/A and C/q. For A < 0 the double cone holds the segment between the
roots; for A > 0 the two half-lines outside them, of which the forward nappe's is the upper one when
ω·a > 0 and the lower one otherwise; A = 0 (a ray parallel to a generator) is the A > 0 case with one root
at infinity. Clipping by the slab t = (w + sω)·a ∈ [0, L] (which also drops the backward nappe) and by
s ∈ [0, depth] leaves the chord [s_in, s_out]; an end that is a root (not clipped) is a shell fragment.
At a fragment x − P = v⃗ with t = v⃗·a the outward normal is n = (κ v⃗ − t a)/(t sin θ_c), so
n·ω = (κ v⃗·ω − t ω·a)/(t sin θ_c) needs no normalisation.

Every division is guarded (`safe_div`), square roots take max(·, 0), |n·ω| and v are clamped to [0, 1]:
no NaN/Inf for any finite input, the camera inside the cone, rays along the axis or grazing the shell,
θ_c → 0 or → 90°, L → 0 (tests/test_light_cones.py, hypothesis). ``chord`` is +∞ only for a chord through
the apex itself, where the physical integral of 1/r² diverges too (as §1's).

Units: positions and lengths in metres, angles in radians, k in W/m²/sr (the shell's radiance), K in
W/m/sr.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .arrays import check_range, clamp01, evaluate, is_drjit, is_jax, safe_div, safe_sqrt, split3
from .methods import Input, Method, Param, method_table
from .volumetric_lightning import METHODS as LIGHTNING_METHODS

__all__ = ["cone_chord", "light_cone_shell"]

_BIG = 1e30  # "infinity" of a half-line chord end (finite, so that products stay finite)
_TINY = 1e-30


# ===================================================================================== kernels (ops text)
def _chord(ops, ox, oy, oz, wx, wy, wz, px, py, pz, ax, ay, az, half_angle, length, depth):
    """The view ray's chord through the cone (module docstring): (s_in, s_out, entry_is_shell,
    exit_is_shell, valid, entry n·ω, exit n·ω, entry v, exit v)."""
    norm = ops.sqrt(wx * wx + wy * wy + wz * wz)  # any direction of non-zero length is normalised here
    wx, wy, wz = safe_div(ops, wx, norm), safe_div(ops, wy, norm), safe_div(ops, wz, norm)
    cos_c = ops.cos(half_angle)
    sin_c = ops.sin(half_angle)
    kappa = cos_c * cos_c
    vx, vy, vz = ox - px, oy - py, oz - pz
    da = wx * ax + wy * ay + wz * az  # ω·a
    va = vx * ax + vy * ay + vz * az  # w·a
    dv = wx * vx + wy * vy + wz * vz  # ω·w
    vv = vx * vx + vy * vy + vz * vz
    qa = da * da - kappa * (wx * wx + wy * wy + wz * wz)
    qb = da * va - kappa * dv
    qc = va * va - kappa * vv
    disc = qb * qb - qa * qc
    real = disc >= 0.0
    sq = safe_sqrt(ops, disc)
    q = -(qb + ops.select(qb >= 0.0, sq, -sq))
    a_eff = ops.select(ops.abs(qa) > _TINY, qa, _TINY)
    r1 = ops.clip(q / a_eff, -_BIG, _BIG)
    q_safe = ops.select(ops.abs(q) > _TINY, q, _TINY)
    r2 = ops.select(ops.abs(q) > _TINY, ops.clip(qc / q_safe, -_BIG, _BIG), 0.0)
    lo_r, hi_r = ops.minimum(r1, r2), ops.maximum(r1, r2)
    # the cone's interval along the ray (forward nappe chosen by the slab below)
    inside = a_eff < 0.0  # between the roots
    up = da > 0.0  # A ≥ 0: the forward nappe's half-line
    c_lo = ops.select(inside, lo_r, ops.select(up, hi_r, -_BIG))
    c_hi = ops.select(inside, hi_r, ops.select(up, _BIG, lo_r))
    lo_root = inside | up
    hi_root = inside | ~up
    # the slab t ∈ [0, L]
    moving = ops.abs(da) > _TINY
    da_safe = ops.select(moving, da, 1.0)
    s0 = -va / da_safe
    s1 = (length - va) / da_safe
    held = (va >= 0.0) & (va <= length)  # a ray perpendicular to the axis: inside the slab or never
    t_lo = ops.select(moving, ops.minimum(s0, s1), ops.select(held, -_BIG, _BIG))
    t_hi = ops.select(moving, ops.maximum(s0, s1), ops.select(held, _BIG, -_BIG))
    lo_clip = ops.maximum(t_lo, 0.0)
    hi_clip = ops.minimum(t_hi, depth)
    s_in = ops.maximum(c_lo, lo_clip)
    s_out = ops.minimum(c_hi, hi_clip)
    valid = real & (s_in < s_out)
    entry = valid & lo_root & (c_lo >= lo_clip)
    leave = valid & hi_root & (c_hi <= hi_clip)
    s_in = ops.select(valid, s_in, 0.0)
    s_out = ops.select(valid, s_out, 0.0)

    def fragment(s):
        t = va + s * da
        nw = safe_div(ops, kappa * (dv + s) - t * da, ops.maximum(t, 0.0) * sin_c)
        v = clamp01(ops, 1.0 - safe_div(ops, t, length))
        return ops.minimum(ops.abs(nw), 1.0), v

    n_in, v_in = fragment(s_in)
    n_out, v_out = fragment(s_out)
    return s_in, s_out, entry, leave, valid, n_in, n_out, v_in, v_out


def _shell_kernel(
    ops, ox, oy, oz, wx, wy, wz, px, py, pz, ax, ay, az, half_angle, length, depth, k, p, q, back
):
    """The seed's shell: k·Σ_fragments |n·ω|^p·v^q over the entry fragment and, where ``back`` = 1, the exit
    fragment (module docstring)."""
    _, _, entry, leave, _, n_in, n_out, v_in, v_out = _chord(
        ops, ox, oy, oz, wx, wy, wz, px, py, pz, ax, ay, az, half_angle, length, depth
    )
    front = ops.power(n_in, p) * ops.power(v_in, q)
    rear = ops.power(n_out, p) * ops.power(v_out, q)
    total = ops.select(entry, front, 0.0) + ops.select(leave, rear, 0.0) * back
    return k * total


def _chord_kernel(ops, ox, oy, oz, wx, wy, wz, px, py, pz, ax, ay, az, half_angle, length, depth, k):
    """§1's inverse-square closed form over the chord: K·∫_{s_in}^{s_out} ds/r² (hard-edged cone, T = 1)."""
    s_in, s_out, _, _, _, _, _, _, _ = _chord(
        ops, ox, oy, oz, wx, wy, wz, px, py, pz, ax, ay, az, half_angle, length, depth
    )
    span = s_out - s_in
    seg = {
        "ox": ox + s_in * wx, "oy": oy + s_in * wy, "oz": oz + s_in * wz,
        "dx": span * wx, "dy": span * wy, "dz": span * wz,
        "lx": px, "ly": py, "lz": pz,
    }  # fmt: skip
    return LIGHTNING_METHODS["inverse-square"](ops, seg, {"k": k})


def _chord_length_kernel(ops, ox, oy, oz, wx, wy, wz, px, py, pz, ax, ay, az, half_angle, length, depth):
    """The chord's length s_out − s_in (m; 0 where the ray misses the cone)."""
    s_in, s_out, _, _, _, _, _, _, _ = _chord(
        ops, ox, oy, oz, wx, wy, wz, px, py, pz, ax, ay, az, half_angle, length, depth
    )
    return s_out - s_in


# ===================================================================================== methods (data)
INPUTS = (
    Input("ox", "m", "camera position o, x", (-100.0, 100.0)),
    Input("oy", "m", "camera position o, y", (-100.0, 100.0)),
    Input("oz", "m", "camera position o, z", (-100.0, 100.0)),
    Input("wx", "1", "view direction ω (normalised by the kernel), x", (-1.0, 1.0)),
    Input("wy", "1", "view direction ω, y", (-1.0, 1.0)),
    Input("wz", "1", "view direction ω, z", (-1.0, 1.0)),
    # (the apex's interval is narrower than o's only so that the domain's corners never put it on o)
    Input("px", "m", "cone apex P (the lamp), x", (-90.0, 90.0)),
    Input("py", "m", "cone apex P, y", (-90.0, 90.0)),
    Input("pz", "m", "cone apex P, z", (-90.0, 90.0)),
    Input("ax", "1", "unit cone axis a (the beam's direction), x", (-1.0, 1.0)),
    Input("ay", "1", "unit cone axis a, y", (-1.0, 1.0)),
    Input("az", "1", "unit cone axis a, z", (-1.0, 1.0)),
    Input("half_angle", "rad", "cone half-angle θ_c", (1e-4, 1.5)),
    Input("length", "m", "cone length L along the axis (the mesh's rim)", (1e-3, 100.0)),
    Input("depth", "m", "scene depth along the view ray (the depth test)", (0.0, 1e4)),
)
"""Per-pixel inputs of every method (the experiment passes float32 pixels). The kernels normalise ω (a zero
direction gives 0); the axis must be unit length (the cone's frame)."""

SHELL_PARAMS = {
    "k": Param(1.0, 0.0, math.inf, unit="W/m²/sr", description="overall level of a shell fragment"),
    "p": Param(1.0, 0.0, 16.0, unit="1", description="edge-fade exponent on |n·ω| (tangent-space view z)"),
    "q": Param(2.0, 0.0, 16.0, unit="1", description="distance-attenuation exponent on v (seed: v², q = 2)"),
}

METHODS = method_table(
    [
        Method(
            "shell",
            "seed shell, both faces",
            _shell_kernel,
            inputs=INPUTS,
            params=SHELL_PARAMS,
            fixed={"back": 1.0},
            quantity="spot_inscattered_radiance",
            formula="L = k·Σ_fragments |n·ω|^p·v^q, v = 1 − t/L (entry and exit fragments, culling off)",
            source="seed 000:1026-1044 (tangent-space edge fade, v² attenuation; noise left out)",
            description="The cone mesh drawn additively with culling off: entry and exit fragments add.",
        ),
        Method(
            "shell-front",
            "seed shell, front faces",
            _shell_kernel,
            inputs=INPUTS,
            params=SHELL_PARAMS,
            fixed={"back": 0.0},
            quantity="spot_inscattered_radiance",
            formula="L = k·|n·ω|^p·v^q at the entry fragment (back faces culled)",
            source="seed 000:1026-1044 (tangent-space edge fade, v² attenuation; noise left out)",
            description="Back faces culled: one fragment from outside, none from inside the cone.",
        ),
        Method(
            "chord",
            "§1 integral over the chord",
            _chord_kernel,
            inputs=INPUTS,
            params={"k": Param(1.0, 0.0, math.inf, unit="W/m/sr", description="σ_s·I/(4π)")},
            quantity="spot_inscattered_radiance",
            formula="L = K·∫_chord ds/r² = K·|d|·∠/|c × d| on the ray's chord through the cone",
            source="§1 (volumetric-lightning inverse-square) restricted to the cone: hard edge, T = 1",
            description="Exact single scattering of a hard-edged spot light without extinction.",
        ),
    ]
)
"""The family's methods: ``METHODS[id](ops, inputs, params)`` runs the kernel text on one ops namespace;
`rtfit.fitting.fit_method` fits (k, p, q) of the shells and K of ``chord`` through their JAX runs."""


def _given_kernel(ops, single_scattering):
    """The exact row: single scattering of the spot (Mitsuba's linear-in-angle profile) with extinction and
    the medium's phase function along the view ray's stretch, integrated by
    `rtfit.reference.single_scattering.spot_single_scattering` (not importable from here), passed through."""
    return single_scattering


QUADRATURE = Method(
    "quadrature",
    "single scattering of the spot with extinction (quadrature, exact)",
    _given_kernel,
    inputs=(Input("single_scattering", "W/m²/sr", "the quadrature of the ray's single scattering"),),
    exact=True,
    quantity="spot_inscattered_radiance",
    formula="L = σ_s ∫ I·f(θ)·p(cos ϑ)·e^(−σ_t(s − s₀ + r))/r² ds, f Mitsuba's linear-in-angle profile",
    source="rtfit.reference.single_scattering.spot_single_scattering",
    description="The exact row of `rtfit audit`: must sit at the reference's noise where nothing shadows "
    "the medium (not one of `METHODS`: the experiment compares its quadrature on its own).",
)
"""The exact row the audit adds to `METHODS` in the registry (``experiments.families.METHOD_TABLES``)."""

CHORD_LENGTH = Method(
    "chord-length",
    "chord length through the cone",
    _chord_length_kernel,
    inputs=INPUTS,
    quantity="length",
    formula="s_out − s_in",
    source="ray–cone intersection (module docstring)",
    description="How long the view ray stays inside the cone (m).",
)
"""The chord length of the view ray through the cone (the experiment's error axis), the same text."""


# ===================================================================================== public API
def _inputs(origin, direction, apex, axis, half_angle, length, depth) -> list:
    """Validated kernel arguments: four 3-vectors (finite), θ_c ∈ (0, π/2), L > 0, depth ≥ 0 (one-line
    ValueError otherwise; Dr.Jit and JAX arrays are not checked, the kernel clamps)."""
    out = []
    for v, name in ((origin, "origin"), (direction, "direction"), (apex, "apex"), (axis, "axis")):
        comps = split3(v, name)
        for cpt in comps:
            if not (is_drjit(cpt) or is_jax(cpt)):
                arr = np.asarray(cpt, dtype=np.float64)
                if arr.size and not np.all(np.isfinite(arr)):
                    raise ValueError(f"{name} must be finite (got {arr[~np.isfinite(arr)].flat[0]!r})")
        out += list(comps)
    half_angle = check_range(
        "half_angle", half_angle, 0.0, math.pi / 2, lo_open=True, interval="(0, π/2) rad"
    )
    length = check_range("length", length, 0.0, 1e30, lo_open=True, interval="(0, 1e30] m")
    depth = check_range("depth", depth, 0.0, 1e30, interval="[0, 1e30] m")
    return [*out, half_angle, length, depth]


def light_cone_shell(
    origin, direction, apex, axis, half_angle, length, depth: Any = 1e30, k: Any = 1.0, p: Any = 1.0,
    q: Any = 2.0, back: bool = True,
):  # fmt: skip
    """The seed's shell radiance k·Σ|n·ω|^p·v^q (module docstring) for view rays o + sω (``direction``
    unit), a cone of apex ``apex``, unit ``axis``, ``half_angle`` (rad) and ``length`` (m); fragments beyond
    ``depth`` (m) are hidden. Vectors: NumPy arrays of shape (..., 3) or 3-sequences; scalars broadcast.
    ``back``: add the exit (back-face) fragment too (culling off)."""
    args = _inputs(origin, direction, apex, axis, half_angle, length, depth)
    k = check_range("k", k, 0.0, 3.4e38, interval="[0, 3.4e38] W/m²/sr")
    p = check_range("p", p, 0.0, 16.0)
    q = check_range("q", q, 0.0, 16.0)
    method = METHODS["shell" if back else "shell-front"]
    return method.evaluate(dict(zip(method.input_names, args, strict=True)), {"k": k, "p": p, "q": q})


def cone_chord(origin, direction, apex, axis, half_angle, length, depth=1e30):
    """Length (m) of the view ray's chord through the cone (0 where it misses); arguments as for
    `light_cone_shell`."""
    return evaluate(_chord_length_kernel, *_inputs(origin, direction, apex, axis, half_angle, length, depth))
