r"""Colour bleeding: real-time stand-ins for one diffuse bounce, per RGB channel.

The exact quantity (``bounce_irradiance``, W/m², one value per channel c) is the one-bounce indirect
irradiance at a surface point x with unit normal n:

    E₁,c(x) = ∫_{H(n)} L₁,c(y(x, ω)) (n·ω) dω,    L₁,c(y) = (a_c(y)/π) · E_dir,c(y)

where y(x, ω) is the first surface along ω, a_c(y) its diffuse albedo in channel c and E_dir,c(y) the direct
irradiance the lights give it (with their shadows). With K directions ω_k distributed as (n·ω)/π,
E₁,c ≈ (1/K) Σ_k a_c(y_k) E_dir,c(y_k): the **gather** row below, which an engine computes by tracing K rays
and reading its direct-light buffer at the hits. The two seeds replace E_dir by one ambient constant I (W/m²,
fitted) and weight each hit by a function of its distance d_k:

* **Seed 000:3083-3087** (Evans 2006, §9.9 "Approximate colour bleeding"): the sky-occlusion SDF is computed
  per channel and each object's channel-c SDF is *increased* by a small constant times its diffuse colour,
  so lookups near a red wall are less occluded in red. rtfit reads the SDF's occlusion along the K rays
  (the sdf-occlusion family audits the SDF lookup itself): a hit at distance d occludes 1 − ρ(d) with the
  SDF-like falloff ρ(d) = 1 − e^{−d/D}; biasing its distance by b_c·a_c(y) lets through
  ρ(d + b_c a_c) − ρ(d) more light in channel c. The bleed the seed adds is therefore

      E_c = I · (1/K) Σ_k [ρ(d_k + b_c a_c(y_k)) − ρ(d_k)]                          (``seed-sdf-bias``)

  with the bias constant b_c fitted per channel (the seed gives no value: "a small constant factor"),
  b_c ∈ [0, 10 R] and D ∈ [10⁻² R, 10² R] (R: the scene's AO radius, the scale the audit gives), I fitted.
* **Seed 001:3251-3380** (GameTools D5.3 §2.10, obscurances with colour bleeding): the RGB obscurance map
  W_c = (1/K) Σ_k [ρ(d_k) + (1 − ρ(d_k)) a_c(y_k)], ρ(d) = min(d/d_max, 1)^½, d_max = 0.3 (001:3284, 3326;
  the transfer function is `rtfit.realtime.obscurances.rho_power`, shared). Its colour part beyond the grey
  obscurance W = (1/K) Σ ρ(d_k) is the bounce it stands in for:

      E_c = I · (W_c − W) = I · (1/K) Σ_k (1 − ρ(d_k)) a_c(y_k)             (``rgb-obscurance-seed``)

  with d_max = R (the seed's 0.3 is in its meshes' units) and I fitted; ``rgb-obscurance`` fits d_max and the
  exponent p too.
* **Modern** (``gather``): the ray-traced one-bounce final gather above, reading the direct light at each
  hit (Ritschel, Grosch & Seidel 2009, "Approximating dynamic global illumination in image space": SSDO's
  indirect bounce, a_c · E_dir of the sender; here with world-space rays instead of screen-space samples, as
  a ray-traced engine does). No free parameter: its error is that of K rays and of the direct-light buffer.

Inputs (one mapping per channel): ``channel`` (0, 1, 2: R, G, B, selecting b_c), and per ray k = 1…`RAYS`
``d<k>`` (scene units; a miss: `MISS`, finite so that float32 and fits stay finite), ``a<k>`` (the hit's
albedo in this channel, 0 for a miss) and ``e<k>`` (the direct irradiance at the hit in this channel, W/m²,
0 for a miss). A row on fewer rays (``rays`` fixed, `bleed_on_rays`) reads the first K of them.

Float32: every term is a product of values in [0, 1] with I or e (≤ 10⁶): no overflow; ρ's arguments are
clamped in `rho_power`/`rho_exponential` (misses at 10³⁰ give ρ = 1 exactly, so a miss adds 0 to every row).
Extremes (tests): K = 1, all misses (0), a = 0 (0), a = 1 with d → 0 (seed-sdf-bias: I·(1 − e^{−b/D})),
d_max and D from 10⁻³ to 10³: finite. Erratum: none in either seed's text; the seed 000 form is rtfit's
reading of a prose description (no formula is printed).
"""

from __future__ import annotations

from dataclasses import replace

from .methods import Input, Method, Param, method_table
from .numpy_memo import KeptValues
from .obscurances import MISS, SEED_D_MAX, SEED_EXPONENT, rho_exponential, rho_power

__all__ = [
    "bleed_on_rays",
    "gather_kernel",
    "rgb_obscurance_kernel",
    "sdf_bias_kernel",
]

RAYS = 16
"""Rays per point the quantity carries (d1…d16, a1…a16, e1…e16); rows on fewer read the first K."""
FEW_RAYS = 4
"""The cheaper setting of each row (id ``<row>-k4``): its cost and error beside the K = `RAYS` row."""


def _pick(channel, r, g, b):
    """r, g or b by the channel index 0, 1, 2 (the Lagrange polynomials through 0, 1, 2: plain arithmetic,
    so one text runs on Python floats, NumPy, JAX and Dr.Jit)."""
    c = channel
    return r * (c - 1.0) * (c - 2.0) * 0.5 - g * c * (c - 2.0) + b * c * (c - 1.0) * 0.5


def _rays(kw, rays: int):
    return [(kw[f"d{k}"], kw[f"a{k}"], kw[f"e{k}"]) for k in range(1, rays + 1)]


def _mean(terms, rays: int):
    acc = terms[0]
    for t in terms[1:]:
        acc = acc + t
    return acc * (1.0 / rays)


_KEPT = KeptValues(max_floats=1 << 22, max_entries=16, max_input_floats=(1 << 20) // RAYS)
"""The NumPy run's kept values (`rtfit.realtime.numpy_memo`): a fit evaluates the kernel again and again on
the same rays, and ρ(d_k) does not depend on the biases or I, nor the ray mean on I. At most 2^22 floats
(32 MB; the least recently used dropped first): a TRF Jacobian evaluates the kernel at D ± h and at each
bias ± h before I ± h, so the ray mean at the step's start must outlive about ten others (each one float per
point; ρ(d_k) K per point), and at most 16 entries; points of up to 2^20 / K (`RAYS`) floats."""
MEMOS = (_KEPT,)
"""This module's process-wide memos, emptied between the experiments of a suite (`runner.forget_memos`)."""


# ---------------------------------------------------------------------------------------------- kernels
def sdf_bias_kernel(ops, channel, *, rays=RAYS, d_max=1.0, bias_r=0.1, bias_g=0.1, bias_b=0.1, ambient=1.0,
                    **kw):  # fmt: skip
    """I · (1/K) Σ_k [ρ(d_k + b_c a_k) − ρ(d_k)], ρ(d) = 1 − e^{−d/D} (D = ``d_max``): seed 000:3083-3087."""
    hits = _rays(kw, rays)
    distances = [d for d, _, _ in hits]

    def at_hits(eager: bool):
        rho = (rho_exponential(ops, d, d_max) for d in distances)
        return list(rho) if eager else rho

    def mean(eager: bool):
        b = _pick(channel, bias_r, bias_g, bias_b)
        rho_d = iter(_KEPT.get(ops, ("rho-exponential", rays, d_max), distances, at_hits))
        terms = [rho_exponential(ops, d + b * a, d_max) - next(rho_d) for d, a, _ in hits]
        return _mean(terms, rays)

    arrays = [channel, *distances, *(a for _, a, _ in hits)]
    return ambient * _KEPT.get(ops, ("sdf-bias", rays, d_max, bias_r, bias_g, bias_b), arrays, mean)


def rgb_obscurance_kernel(
    ops, channel, *, rays=RAYS, d_max=SEED_D_MAX, exponent=SEED_EXPONENT, ambient=1.0, **kw
):
    """I · (1/K) Σ_k (1 − min(d_k/d_max, 1)^p) a_k: the RGB obscurance's colour part (001:3284, p = ½)."""
    hits = _rays(kw, rays)

    def mean(eager: bool):
        return _mean([(1.0 - rho_power(ops, d, d_max, exponent)) * a for d, a, _ in hits], rays)

    arrays = [x for d, a, _ in hits for x in (d, a)]
    return ambient * _KEPT.get(ops, ("rgb-obscurance", rays, d_max, exponent), arrays, mean) + 0.0 * channel


def gather_kernel(ops, channel, *, rays=RAYS, **kw):
    """(1/K) Σ_k a_k E_dir,k: the one-bounce final gather over cosine-distributed rays (exact as K → ∞)."""
    return _mean([a * e for _, a, e in _rays(kw, rays)], rays) + 0.0 * channel


# ---------------------------------------------------------------------------------------------- inputs
CHANNEL = Input("channel", "1", "colour channel index: 0 red, 1 green, 2 blue", (0.0, 2.0))
_K = range(1, RAYS + 1)
INPUTS = (
    CHANNEL,
    *(Input(f"d{k}", "scene units", f"hit distance of ray {k} (a miss: {MISS:g})", (0.0, 100.0)) for k in _K),
    *(Input(f"a{k}", "1", f"albedo at ray {k}'s hit, this channel (0: a miss)", (0.0, 1.0)) for k in _K),
    *(Input(f"e{k}", "W/m²", f"direct irradiance at ray {k}'s hit, this channel (0: a miss)", (0.0, 1.0e3))
      for k in _K),
)  # fmt: skip
"""The quantity ``bounce_irradiance``'s inputs (`rtfit.realtime.quantities`)."""
_AMBIENT = Param(1.0, 1e-6, 1e6, unit="W/m²", description="ambient intensity I the bounce is scaled by",
                 published=False)  # fmt: skip
_D = Param(1.0, 1e-2, 1e2, unit="scene units", description="falloff length D of ρ(d) = 1 − e^{−d/D} (× R)",
           published=False)  # fmt: skip
_D_MAX = Param(
    1.0, 1e-3, 1e3, unit="scene units", description="distance d_max beyond which a hit no longer bleeds"
)
_EXPONENT = Param(0.5, 1e-2, 16.0, unit="1", description="exponent p of ρ = min(d/d_max, 1)^p")


def _bias(c: str) -> Param:
    return Param(0.1, 0.0, 10.0, unit="scene units", description=f"SDF bias b_{c} per unit {c} albedo (× R)",
                 published=False)  # fmt: skip


_SDF_BIAS_PARAMS = {
    k: replace(p, log=True)
    for k, p in (("d_max", _D), ("bias_r", _bias("r")), ("bias_g", _bias("g")), ("bias_b", _bias("b")),
                 ("ambient", _AMBIENT))
}  # fmt: skip
"""seed-sdf-bias's parameters, fitted in their logs (`Param.log`): where b_c a_k ≪ D the bleed is
I·b_c/D·(1/K) Σ_k a_k e^{−d_k/D}, a valley along I·b_c/D = const (straight in the logs) that TRF crawled along
in p, a hundred small steps on the Cornell box."""
_Q = "bounce_irradiance"
_ROWS = (
    Method(
        "seed-sdf-bias",
        "Seed: per-channel SDF biased by the surface colour (b_c fitted per channel)",
        sdf_bias_kernel,
        inputs=INPUTS,
        params=_SDF_BIAS_PARAMS,
        quantity=_Q,
        formula="I · (1/K) Σ_k [ρ(d_k + b_c a_c,k) − ρ(d_k)],  ρ(d) = 1 − e^{−d/D}",
        source="Evans 2006 §9.9, seed 000:3083-3087 (rtfit's reading of the prose)",
    ),
    Method(
        "rgb-obscurance-seed",
        "Seed: RGB obscurance's colour part (√(d/d_max), d_max = R; I fitted)",
        rgb_obscurance_kernel,
        inputs=INPUTS,
        params={"ambient": _AMBIENT},
        fixed={"d_max": 1.0, "exponent": SEED_EXPONENT},
        quantity=_Q,
        formula="I · (1/K) Σ_k (1 − min(d_k/d_max, 1)^½) a_c,k",
        source="GameTools D5.3 §2.10, seed 001:3284, 001:3326 (RGB map, 001:3340)",
    ),
    Method(
        "rgb-obscurance",
        "RGB obscurance (d_max, p, I fitted)",
        rgb_obscurance_kernel,
        inputs=INPUTS,
        params={"d_max": _D_MAX, "exponent": _EXPONENT, "ambient": _AMBIENT},
        quantity=_Q,
        formula="I · (1/K) Σ_k (1 − min(d_k/d_max, 1)^p) a_c,k",
        source="001:3284 (p generalised)",
    ),
    Method(
        "gather",
        "One-bounce gather: albedo × direct light at each hit",
        gather_kernel,
        inputs=INPUTS,
        quantity=_Q,
        formula="(1/K) Σ_k a_c,k E_dir,c,k",
        source="Ritschel, Grosch & Seidel 2009 (SSDO's indirect bounce), by world-space rays",
    ),
)


def bleed_on_rays(method: Method, rays: int) -> Method:
    """``method`` on the first ``rays`` rays (1 ≤ K ≤ `RAYS`): id ``<id>-k<K>``, only the inputs it reads."""
    if not 1 <= rays <= RAYS:
        raise ValueError(f"rays must be in [1, {RAYS}] (got {rays!r})")
    keep = {"channel", *(f"{v}{k}" for v in "dae" for k in range(1, rays + 1))}
    return replace(
        method,
        id=f"{method.id}-k{rays}",
        label=f"{method.label}, K = {rays}",
        inputs=tuple(i for i in method.inputs if i.name in keep),
        fixed={**method.fixed, "rays": rays},
    )


METHODS = method_table([*_ROWS, *(bleed_on_rays(m, FEW_RAYS) for m in _ROWS)])
"""The colour-bleeding rows as data (`rtfit.realtime.methods`): each on K = `RAYS` rays and again on the first
`FEW_RAYS` (``<row>-k4``); scale-bearing parameters (D, b_c, d_max) in units of R (the audit multiplies them
by the scene's AO radius)."""
