r"""Caustics: photon hits splatted into the receiver's texture with a Gaussian filter.

The seed (001:887-939, 941-1606; GameTools D5.3, Szirmay-Kalos et al. 2005, "Approximate ray-tracing on
the GPU with distance impostors")
------------------------------------------------------------------------------------------------------
The caustic caster (a glass or metal object) is rendered from the light; each texel of that "photon hit
map" is one photon, traced through the caster (the distance-impostor ``Hit()`` search, 001:1110) to the
receiver, its hit stored as the receiver's texture-atlas coordinates (``g_pPhotonUVTexture``, 001:947-949:
"one snippet represents one photon hit"). Every photon is then drawn as a *snippet* into the receiver's
atlas and blended additively (001:1118); the "power distribution inside a single caustic spot" is "a
Gaussian filter" (``g_pPowerOfSnippetTexelTexture``, 001:953-955). The controls (001:895-906): the number of
photon hits ("the bigger this number the smoother"), the "snippet size" ("the area affected by one photon
hit"), the light's intensity; and (001:1241) "Independent Snippet size ON/OFF – we can adjust the snippets
size automatically or it can be constant".

Errata / what the text leaves out: no formula for the snippet's weight, its size or its normalisation (the
power texture is an image), nor for the "automatic" size. rtfit's reading, stated once here:

* a photon i carries the flux Φ_i (W) the light sends into its texel of the hit map (the seed's "intensity"
  slider is that flux's scale, not a free constant: the fits keep it physical);
* its snippet is the normalised 2-D Gaussian of width h (m), K_h(r) = e^(−r²/(2h²))/(2πh²) (1/m²), so that
  each snippet deposits exactly Φ_i on the receiver (energy conserving);
* the irradiance at a receiver point x is the sum of the snippets over it (W/m²):

      E(x) = Σ_i Φ_i·K_h(|x − x_i|)                                   (``splat-seed``: h constant, fitted)

* the "automatic" size (a reading, after the k-nearest-neighbour width of photon-map density estimation,
  Jensen 1996 §3, and the adaptive splat sizes of Wyman & Davis 2006, "Interactive image-space techniques
  for approximating caustics", I3D): the width follows the photon density where it is read, h(x) = c·r₈(x)
  with r₈(x) the distance from x to its `ADAPT_K`-th nearest photon (a balloon estimator: the width is the
  receiver point's, so that the far photons' sum below stays exact; a per-photon width, the sample-point
  form, is left for later):

      E(x) = Σ_i Φ_i·K_{c·r₈(x)}(|x − x_i|)                            (``splat-adaptive``: c fitted)

* the best gather form for comparison, the photon-map estimate (Jensen 1996, "Global illumination using
  photon maps", eq. 6; a disc of radius r_K around x holding the K nearest photons; parameter-free):

      E(x) = Σ_{k ≤ K} Φ_k / (π·r_K²)                                 (``photon-map``)

Distances are measured in the scene (3-D, m), which is the atlas distance on a receiver mapped at uniform
scale (a plane; seams and stretched charts, which the seed's atlas has, are not modelled). Each pixel reads
its `NEAREST` nearest photons exactly (``d<k>``, ``f<k>``: distance, flux in this channel) and every other
photon binned into `RINGS` rings d_K·γ^(j−1) ≤ d < d_K·γ^j (γ = `RING_RATIO`, the last ring open): ring j's
flux ``g<j>`` at its flux-weighted RMS distance ``q<j>``. The snippet sums run over both, so no photon's
snippet is truncated (a 32-nearest gather alone cut the fitted constant snippets off: their RMSE over the
reference was 2–3× that of the full sum at 16384 photons); the ring approximation e^(−q²/(2h²)) ≈ mean
e^(−d²/(2h²)) over a ring is second order in the ring's width (tests/test_caustics.py: within 1.5 % of
the photon-by-photon sum).

The quality knob is the number N of photons (rows ``<id>-n<N>``, `PHOTON_COUNTS`): more photons cost more
snippets (N quads blended into the atlas) and reduce the noise; the error beside N is the study's table.

Units: lengths m (scene units), flux W per channel, irradiance W/m². Domain: d, q ≥ 0, f, g ≥ 0, h, c > 0.

Float32: distances are clamped to `NO_PHOTON` (1e15 m: a missing photon; d² stays finite), widths floored at
`_MIN_WIDTH` (1e-12 m; the reason: a fitted width at its bound or two coincident photons must not divide by
zero, and 1/(2π·1e-24) is finite in float32); e^(−x) of an overflowed x = +inf is 0, never NaN; a missing
photon has f = 0 and adds exactly 0. No NaN or Inf for inputs in the domain (tests/test_caustics.py).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from .arrays import check_range, evaluate
from .methods import Input, Method, Param, method_table

__all__ = [
    "ADAPT_K",
    "CAUSTIC_INPUTS",
    "NEAREST",
    "NO_PHOTON",
    "PHOTON_COUNTS",
    "RINGS",
    "RING_RATIO",
    "adaptive_splat_irradiance",
    "gaussian_snippet",
    "on_photons",
    "photon_map_irradiance",
    "splat_irradiance",
]

NEAREST = 32
"""K: the nearest photons each receiver point reads (d1…dK, f1…fK, s1…sK)."""
ADAPT_K = 8
"""r₈(x): the distance from the receiver point to its 8th nearest photon (the adaptive width's density)."""
PHOTON_COUNTS = (1024, 4096, 16384)
"""The rows' photon counts N (the seed's hit-map resolutions 32², 64², 128²)."""
RINGS = 40
"""The photons beyond the `NEAREST`: binned into 40 rings d_K·γ^(j−1) ≤ d < d_K·γ^j (γ = `RING_RATIO`; the
last ring open), each one flux g_j at its flux-weighted RMS distance q_j: every photon splats, none is
truncated."""
RING_RATIO = 1.15
NO_PHOTON = 1.0e15
"""A missing photon's distance (m); its flux is 0. Clamped to this in the kernels so that d² is finite."""
_MIN_WIDTH = 1e-12  # m: a width at its bound, or r₈ = 0 (photons on the point), never divides by zero


def gaussian_snippet(ops, d, h):
    """K_h(d) = e^(−d²/(2h²))/(2πh²) (1/m²): one photon's normalised Gaussian snippet (module docstring)."""
    w = ops.maximum(h, _MIN_WIDTH)
    x = ops.minimum(d, NO_PHOTON) / w
    return ops.exp(-0.5 * x * x) / (2.0 * math.pi * w * w)


def _photons(kw, k: int):
    return [(kw[f"d{i}"], kw[f"f{i}"]) for i in range(1, k + 1)]


def _sum(terms):
    acc = terms[0]
    for t in terms[1:]:
        acc = acc + t
    return acc


def _rings(kw, rings: int):
    return [(kw[f"q{j}"], kw[f"g{j}"]) for j in range(1, rings + 1)]


def _splat(ops, kw, width, nearest: int, rings: int):
    near = [f * gaussian_snippet(ops, d, width) for d, f in _photons(kw, nearest)]
    return _sum(near + [g * gaussian_snippet(ops, q, width) for q, g in _rings(kw, rings)])


def _splat_seed_kernel(ops, *, width=0.05, nearest=NEAREST, rings=RINGS, photons=0, **kw):
    """E = Σ_k f_k·K_h(d_k) + Σ_j g_j·K_h(q_j), h = ``width`` (seed 001:953-955, 001:905: constant size)."""
    return _splat(ops, kw, width, nearest, rings)


def _splat_adaptive_kernel(ops, *, scale=1.0, nearest=NEAREST, rings=RINGS, photons=0, **kw):
    """The same with h = c·d₈ (c = ``scale``; 001:1241, "adjust the snippets size automatically")."""
    return _splat(ops, kw, scale * kw[f"d{ADAPT_K}"], nearest, rings)


def _photon_map_kernel(ops, *, nearest=NEAREST, rings=RINGS, photons=0, **kw):
    """E = Σ_{k ≤ K} f_k/(π r_K²), r_K = d_K (Jensen 1996 eq. 6): the gather over the K nearest photons."""
    terms = _photons(kw, nearest)
    r = ops.maximum(ops.minimum(terms[-1][0], NO_PHOTON), _MIN_WIDTH)
    return _sum([f for _, f in terms]) / (math.pi * r * r)


# ---------------------------------------------------------------------------------------------- inputs
_K = range(1, NEAREST + 1)
CAUSTIC_INPUTS = (
    *(Input(f"d{k}", "m", f"distance to photon {k}, photons by distance ({NO_PHOTON:g}: none)", (0.0, 100.0))
      for k in _K),
    *(Input(f"f{k}", "W", f"flux of photon {k}, this channel (0: none)", (0.0, 10.0))
      for k in _K),
    *(Input(f"g{j}", "W", f"flux of the photons beyond the {NEAREST} nearest in ring {j}, this channel",
            (0.0, 100.0)) for j in range(1, RINGS + 1)),
    *(Input(f"q{j}", "m", f"ring {j}'s flux-weighted RMS distance ({NO_PHOTON:g}: empty)", (0.0, 100.0))
      for j in range(1, RINGS + 1)),
)  # fmt: skip
"""The quantity ``caustic_irradiance``'s inputs (`rtfit.realtime.quantities`)."""

_WIDTH = Param(0.05, 0.002, 2.0, unit="m", description="snippet width h (Gaussian σ; × the caster's radius)",
               published=False)  # fmt: skip
_SCALE = Param(1.0, 0.02, 20.0, unit="1", description="adaptive width h = c·r₈ (r₈: 8th nearest photon)",
               published=False)  # fmt: skip

_ROWS = (
    Method(
        id="splat-seed",
        label="seed: Gaussian snippets of constant width",
        kernel=_splat_seed_kernel,
        inputs=CAUSTIC_INPUTS,
        params={"width": _WIDTH},
        quantity="caustic_irradiance",
        formula="E = Σ Φ_i·e^(−r_i²/(2h²))/(2πh²)",
        source="seed 001:887-939, 941-1606 (snippets 001:947-955, 001:1118; size 001:905, 001:1241)",
    ),
    Method(
        id="splat-adaptive",
        label="Gaussian snippets sized by the photon density",
        kernel=_splat_adaptive_kernel,
        inputs=CAUSTIC_INPUTS,
        params={"scale": _SCALE},
        quantity="caustic_irradiance",
        formula="E = Σ Φ_i·e^(−r_i²/(2h²))/(2πh²), h = c·r₈(x) (8th nearest photon)",
        source="seed 001:1241 (automatic snippet size); Wyman & Davis 2006 (I3D, adaptive splats)",
    ),
    Method(
        id="photon-map",
        label=f"photon-map gather, K = {NEAREST}",
        kernel=_photon_map_kernel,
        inputs=CAUSTIC_INPUTS,
        quantity="caustic_irradiance",
        formula=f"E = Σ_(k≤{NEAREST}) Φ_k/(π r_{NEAREST}²)",
        source="Jensen 1996 (Rendering Techniques, photon maps, eq. 6)",
    ),
)


def on_photons(method: Method, photons: int) -> Method:
    """``method`` on a set of N = ``photons`` photons: id ``<id>-n<N>`` (its inputs: that set's K nearest)."""
    if isinstance(photons, bool) or int(photons) != photons or photons < 1:
        raise ValueError(f"photons must be a positive integer (got {photons!r})")
    return replace(
        method,
        id=f"{method.id}-n{photons}",
        label=f"{method.label}, N = {photons}",
        fixed={**method.fixed, "photons": int(photons)},
    )


METHODS = method_table([on_photons(m, n) for n in PHOTON_COUNTS for m in _ROWS])
"""The caustics rows as data: each form at each photon count of `PHOTON_COUNTS` (id ``<form>-n<N>``); the
snippet width h in units of the caster's radius (the audit multiplies it by the radius)."""


# ============================================================================================ public API
def _columns(name: str, a, k: int) -> dict:
    arr = np.asarray(a, np.float64)
    if arr.ndim != 2 or arr.shape[1] != k:
        raise ValueError(f"{name} must be an (N, {k}) array of the K nearest photons (got shape {arr.shape})")
    return {f"{name}{i + 1}": arr[:, i] for i in range(k)}


def _inputs(d, flux) -> tuple[int, dict]:
    k = np.shape(d)[1] if np.ndim(d) == 2 else 0
    if k < 1:
        raise ValueError("d must be an (N, K) array of distances to the K nearest photons, K >= 1")
    d, flux = np.asarray(d, np.float64), np.asarray(flux, np.float64)
    check_range("d", d, 0.0, math.inf, interval="[0, inf] (m)")
    check_range("flux", flux, 0.0, 3.4e38, interval="[0, 3.4e38] (W)")
    return k, {**_columns("d", d, k), **_columns("f", flux, k)}


def _run(kernel, k: int, cols: dict, **params):
    names = sorted(cols)

    def wrapped(ops, *args):
        return kernel(ops, nearest=k, rings=0, **dict(zip(names, args[: len(names)], strict=True)),
                      **dict(zip(params, args[len(names):], strict=True)))  # fmt: skip

    return evaluate(wrapped, *(cols[n] for n in names), *params.values())


def splat_irradiance(d, flux, width):
    """E (W/m²) at N points from the K photons each reads (its nearest, or every photon: the exact splat):
    ``d`` (N, K) m, ``flux`` (N, K) W, snippets of constant width h = ``width`` m (> 0): the seed's form."""
    check_range("width", width, 0.0, 1e30, lo_open=True, interval="(0, 1e30] (m)")
    k, cols = _inputs(d, flux)
    return _run(_splat_seed_kernel, k, cols, width=width)


def adaptive_splat_irradiance(d, flux, scale=1.0):
    """E (W/m²) from snippets of width h = c·d₈: ``d`` (N, K ≥ `ADAPT_K`) sorted by distance, so that its
    `ADAPT_K`-th column is the distance to the point's 8th nearest photon; ``scale`` c > 0."""
    check_range("scale", scale, 0.0, 1e30, lo_open=True, interval="(0, 1e30]")
    k, cols = _inputs(d, flux)
    if k < ADAPT_K:
        raise ValueError(f"d must hold at least the {ADAPT_K} nearest photons per point (got K = {k})")
    return _run(_splat_adaptive_kernel, k, cols, scale=scale)


def photon_map_irradiance(d, flux):
    """E (W/m²) = Σ flux/(π d_K²): the photon-map gather over the K nearest photons (``d`` sorted)."""
    k, cols = _inputs(d, flux)
    return _run(_photon_map_kernel, k, cols)
