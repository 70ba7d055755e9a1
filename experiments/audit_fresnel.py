"""The ``fresnel`` family in `rtfit audit`: the Fresnel reflectance of every visible conductor or dielectric
at the angle the camera sees it, as Mitsuba computes it, against Schlick and its variants
(`rtfit.realtime.fresnel.METHODS`).

For each reflective shape (`rtfit.reference.reflective_shapes.REFLECTIVE_BSDFS`) of a Mitsuba XML scene, or
of an rtfit TOML scene (a ``mitsuba_xml`` shape keeping its file's BSDFs), one case ``fresnel-<i>`` (one
material):

* **pixels**: the pixel-centre camera rays whose first hit is that shape (`shape_pixels`); on a conductor
  or plastic only those that see its front (cos θ > 0: Mitsuba's conductor reflects nothing from behind);
* **inputs** per pixel and RGB channel (`FamilyCase.channel_inputs`, one mapping per channel):
  ``cos_theta`` = |wi·n| in the BSDF's shading frame at Mitsuba's own first hit; ``eta`` and ``k`` the BSDF's
  own index read from the loaded plugin (``mi.traverse``: a conductor's η, k per channel, a dielectric's
  relative η = int_ior/ext_ior with k = 0); a dielectric seen from inside gets 1/η (total internal reflection
  beyond the critical angle, as Mitsuba's ``fresnel`` does);
* **reference** (deterministic, `AuditReference.deterministic`: no sampling, noise floor zero, not cached):
  on a smooth ``conductor`` or ``dielectric``, **the BSDF itself**: one ``bsdf.sample`` with the
  lobe-selecting sample at 0 (a dielectric's reflection lobe), whose w·pdf is F·specular_reflectance,
  divided by the uniform ``specular_reflectance``. On a rough BSDF (``roughconductor``,
  ``roughdielectric``), on ``plastic``/``roughplastic`` (their coating) or on a smooth BSDF whose
  specular_reflectance is a texture: Mitsuba's own ``fresnel_conductor``/``fresnel`` on the BSDF's η, k
  at cos θ, the Fresnel factor of the specular lobe at the mirror direction, whose half vector is the
  normal (what a microfacet BSDF multiplies its D·G term by there). A ``thindielectric`` (reflectance
  2R/(1 + R) of two interfaces) and a BSDF whose η or k is a texture give no case.

Rows: Schlick with F0 from the IOR, with a fitted exponent, the seed's slider form (F0 fitted), its rim
term (as printed and with fitted ranges), its metal shortcut, Hoffman's F82 tint, and the exact dielectric
and conductor Fresnel (``exact=True``: z-checked against the reference; ``exact-dielectric`` only on
materials with k = 0). Fits (the engine's): Schlick's exponent p, the slider's F0 (and p), the rim ranges,
per material over its pixels and three channels.
"""

from __future__ import annotations

import time

import numpy as np

from rtfit.realtime.arrays import to_drjit
from rtfit.realtime.fresnel import METHODS
from rtfit.reference.reflective_shapes import REFLECTIVE_BSDFS

from .audit import Applicability, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_geometry import rays, reflective_shape, shape_view, visible_subset
from .audit_setup import AuditReference, AuditSetup
from .shipped import Sizes

__all__ = ["FAMILY", "SCENES", "fresnel_cases", "material_ior", "mitsuba_fresnel"]

FORMAT = 1
_SAMPLED = frozenset({"conductor", "dielectric"})
"""Smooth BSDFs whose reference is their own delta-reflection sample."""
_DIELECTRIC = frozenset({"dielectric", "roughdielectric", "plastic", "roughplastic"})
_UNAUDITED = frozenset({"thindielectric"})  # two interfaces: 2R/(1 + R), not one Fresnel term

SCENES = (
    Sizes(full=(64, 64, 64), quick=(24, 24, 8)).scene(
        "fresnel_spheres.xml",
        "a smooth gold sphere, a glass sphere and a rough copper sphere under a constant white sky",
    ),
)


def _uniform(params, name: str) -> np.ndarray | None:
    """The (3,) RGB value of the BSDF parameter ``name`` (``name`` or ``name.value``; a grey value copied to
    the three channels), or None where it is not a constant (a texture)."""
    keys = [k for k in params.keys() if k == name or k.startswith(name + ".")]
    if not keys:
        return None
    if keys not in ([name], [f"{name}.value"]):
        return None
    v = np.array(params[keys[0]], np.float64).reshape(-1)
    return np.broadcast_to(v, (3,)).copy() if v.size in (1, 3) else None


def material_ior(mi, bsdf, plugin: str) -> tuple[np.ndarray, np.ndarray] | None:
    """(η, k), each (3,) per RGB channel, of a loaded reflective BSDF: a conductor's complex index, a
    dielectric's or plastic's relative η = int_ior/ext_ior with k = 0; None where η or k is a texture."""
    params = mi.traverse(bsdf)
    eta = _uniform(params, "eta")
    if eta is None:
        return None
    if plugin in _DIELECTRIC:
        return eta, np.zeros(3)
    k = _uniform(params, "k")
    return (eta, k) if k is not None else None


def mitsuba_fresnel(mi, cos_theta, eta: float, k: float, dielectric: bool) -> np.ndarray:
    """Mitsuba's own Fresnel at signed cos θ_i (N,): ``mi.fresnel`` (dielectric: a negative cosine is the
    inside, 1/η) or ``mi.fresnel_conductor`` (cos θ_i > 0 assumed by Mitsuba)."""
    c = to_drjit(mi.Float, cos_theta)
    if dielectric:
        return np.array(mi.fresnel(c, mi.Float(float(eta)))[0], np.float64)
    return np.array(mi.fresnel_conductor(c, mi.Complex2f(float(eta), float(k))), np.float64)


def _shape(setup: AuditSetup, app: Applicability):
    return reflective_shape(setup, app, "fresnel")


def fresnel_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """One case per visible conductor or dielectric (module docstring); none where the camera sees none of
    it, for a thin dielectric and for an η or k given as a texture."""
    mi, scene = setup.mi, setup.scene
    index, shape, plugin = _shape(setup, app)
    ior = material_ior(mi, shape.bsdf(), plugin)
    if plugin in _UNAUDITED or ior is None:
        return []
    t0 = time.perf_counter()
    origins, dirs, sees = shape_view(setup, index)
    if not sees.any():
        return []
    ray = rays(mi, origins[sees], dirs[sees])
    si = scene.ray_intersect(ray)
    wi_z = np.array(si.wi.z, np.float64)
    dielectric = plugin in _DIELECTRIC
    front = np.ones_like(wi_z, bool) if plugin in ("dielectric", "roughdielectric") else wi_z > 0.0
    eta, kappa = ior
    params = mi.traverse(shape.bsdf())
    spec = _uniform(params, "specular_reflectance") if "specular_reflectance.value" in params.keys() else None
    sampled = plugin in _SAMPLED and (
        spec is not None or not any("specular_reflectance" in k for k in params.keys())
    )
    if sampled:
        bsdf = shape.bsdf()
        ctx = mi.BSDFContext()
        bs, w = bsdf.sample(ctx, si, mi.Float(0.0), mi.Point2f(0.5, 0.5), si.is_valid())
        ok = mi.has_flag(bs.sampled_type, mi.BSDFFlags.DeltaReflection)
        value = np.array(mi.Color3f(w) * bs.pdf, np.float64).T.reshape(-1, 3)
        value = np.where(np.array(ok, bool)[:, None], value, 0.0) / (spec if spec is not None else 1.0)
        how = f"Mitsuba's {plugin} BSDF: one bsdf.sample, the delta-reflection lobe's w·pdf"
        how += " / specular_reflectance" if spec is not None and np.any(spec != 1.0) else " (= F)"
    else:
        value = np.stack(
            [mitsuba_fresnel(mi, wi_z if dielectric else np.abs(wi_z), eta[c], kappa[c], dielectric)
             for c in range(3)],
            axis=1,
        )  # fmt: skip
        how = f"Mitsuba's {'fresnel' if dielectric else 'fresnel_conductor'} on the {plugin}'s η, k"
    keep = front & np.isfinite(value).all(axis=1)
    if not keep.any():
        return []
    mask = visible_subset(setup.mask, sees, keep)
    cos = np.abs(wi_z[keep])
    inside = wi_z[keep] < 0.0
    channel = tuple(
        {
            "cos_theta": cos,
            "eta": np.where(inside, 1.0 / eta[c], eta[c]) if dielectric else np.full(cos.shape, eta[c]),
            "k": np.full(cos.shape, kappa[c]),
        }
        for c in range(3)
    )
    seconds = time.perf_counter() - t0
    reference = AuditReference.deterministic(
        mask,
        value[keep],
        (FORMAT, setup.scene_digest, app.part, plugin, tuple(eta), tuple(kappa)),
        seconds,
        "Fresnel reflectance F at the viewing angle (dimensionless)",
        how + " at the pixel-centre rays' first hits (no sampling, not cached)",
        "Mitsuba's Fresnel is a closed form at each hit: deterministic, noise floor zero",
    )
    rows = {mid: m for mid, m in METHODS.items() if mid != "exact-dielectric" or not np.any(kappa > 0.0)}
    notes = [
        f"{plugin}: η = {_rgb(eta)}, k = {_rgb(kappa)} per RGB channel (read from the loaded BSDF)",
        f"cos θ from {cos.min():.3g} to {cos.max():.3g} over {int(mask.sum())} pixels"
        + (f"; {int(inside.sum())} seen from inside (η → 1/η)" if inside.any() else ""),
    ]
    if REFLECTIVE_BSDFS[plugin].rough:
        notes.append(
            "rough BSDF: the Fresnel factor at the mirror direction (half vector = normal) is compared"
        )
    return [
        FamilyCase(
            id=f"fresnel-{app.source}",
            label=f"{app.part}, Fresnel reflectance",
            reference=reference,
            channel_inputs=channel,
            parameters={
                "shape": app.part,
                "bsdf": plugin,
                "eta": [float(v) for v in eta],
                "k": [float(v) for v in kappa],
                "reference": "bsdf.sample" if sampled else "fresnel formula",
                "pixels": int(mask.sum()),
            },
            units="1",
            notes=tuple(notes),
            methods=rows,
        )
    ]


def _rgb(v) -> str:
    return "(" + ", ".join(f"{float(c):.4g}" for c in v) + ")"


_RULE_WORDS = (
    "{part}: an engine shades its reflection with a Fresnel approximation (Schlick) instead of the exact "
    "Fresnel of its index of refraction",
    "Mitsuba's own Fresnel reflectance of the BSDF at each visible pixel's viewing angle",
    "none: the smooth BSDF's delta-reflection sample (its Fresnel weight), or Mitsuba's fresnel / "
    "fresnel_conductor on a rough BSDF's η, k (deterministic: noise floor zero)",
)

FAMILY = AuditFamily(
    name="fresnel",
    quantity="fresnel_reflectance",
    cases=fresnel_cases,
    describe=(
        "Per visible conductor or dielectric (and their rough versions, and plastic's coating): the Fresnel "
        "reflectance F at each pixel's viewing angle as Mitsuba computes it — the smooth BSDF's own "
        "delta-reflection weight, or Mitsuba's fresnel/fresnel_conductor on a rough BSDF's η, k (the "
        "Fresnel factor at the mirror direction) — against Schlick (F0 from the IOR, fitted exponent), the "
        "seeds' slider, rim and metal forms, Hoffman's F82 tint and the exact dielectric and conductor "
        "formulas (z-checked). A thin dielectric is not audited (two interfaces: 2R/(1 + R))."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=tuple(
        Rule("fresnel", role, (kind,), *_RULE_WORDS, supplies=frozenset({"cos_theta", "eta", "k"}))
        for role, kind in (("reflectance", "reflective-shape"), ("glossy reflectance", "rough-shape"))
    ),
)
