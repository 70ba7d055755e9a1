r"""The height-fog conversion every engine shares: the `Engine` record, a fog method in its properties.

rtfit's height fog (`rtfit.realtime.height_fog`) has the extinction σt(z) = b·e^(−c·z) per metre, z the height
in metres, with the optical depth τ = ∫ σt ds along the view ray, the transmittance T = e^(−τ) and the
shading L = L₀·T + C·(1 − T). Every fitted method whose parameters hold ``b`` and ``c`` in 1/m (`is_fog`: the
height-fog optical-depth forms and shading models, the aerial-perspective fog) is converted by
`convert_method`; the conversion of each engine is written once, as a pair (`Engine.to_engine`,
`Engine.from_engine`) of closed forms in that engine's module (`engine_presets_unreal`, `engine_presets_hdrp`,
`engine_presets_godot`), with the engine's own fog formula beside it.

The ``phase`` model's lobe C₁·4π·p_HG(θ, g) becomes Unreal's directional inscattering, a + k·max(cos θ, 0)^n
fitted by least squares over the sphere (`hg_as_power_lobe`) with 512-point Gauss–Legendre nodes, made on
first use (not at import: `rtfit --help` would pay for them). `make_preset` is the one maker of a `Preset`
(fog, sky and SH sections alike).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from rtfit.realtime import NUMPY_OPS
from rtfit.realtime.phase import hg_phase_kernel

from .preset_records import ConvertError, EngineValue, MethodLike, Preset, plain_value

__all__ = ["LN2", "LOBE_EXPONENTS", "Engine", "convert_method", "hg_as_power_lobe", "is_fog", "make_preset"]

LN2 = math.log(2.0)
"""ln 2: Unreal's and Godot's fog work in base 2."""
_COLOUR = ("r0", "g0", "b0")
_LOBE = ("r1", "g1", "b1", "g")


@dataclass(frozen=True)
class Engine:
    """One engine's conversion: ``to_engine(b, c, base, colour)`` → its properties; ``from_engine(values,
    base)`` → (b, c, colour) back; ``base``: the height (m) its fog is anchored at (``anchor``: what the
    engine calls it); ``colour``: whether the constant colour C₀ has a property; ``lost``: what the engine's
    model does not hold; ``sources``: the documentation."""

    name: str
    title: str
    anchor: str
    to_engine: Callable[[float, float, float, tuple | None], dict[str, float | tuple]]
    from_engine: Callable[[Mapping[str, float | tuple], float], tuple[float, float, tuple | None]]
    units: Mapping[str, str]
    colour: bool
    lost: tuple[str, ...]
    sources: tuple[str, ...]
    base_from_domain: bool = True


# ------------------------------------------------------------------ the phase lobe as Unreal's power lobe
@functools.cache
def _nodes() -> tuple[np.ndarray, np.ndarray]:
    """512-point Gauss–Legendre nodes μ and weights on [−1, 1], made on first use (at import they cost
    `rtfit --help` seconds: an eigen-decomposition of a 512 × 512 matrix)."""
    return np.polynomial.legendre.leggauss(512)


LOBE_EXPONENTS = np.geomspace(1.0, 512.0, 600)
"""The exponents n `hg_as_power_lobe` searches (Unreal's DirectionalInscatteringExponent)."""


def _lobe_fit(w: np.ndarray, n: float) -> tuple[float, float, float]:
    """(a, k, squared error) of the least-squares a + k·max(μ, 0)^n ≈ w(μ) over the sphere (dΩ = 2π dμ)."""
    mu, mu_w = _nodes()
    basis = np.stack([np.ones_like(mu), np.maximum(mu, 0.0) ** n], axis=1)
    sw = np.sqrt(mu_w)
    (a, k), *_ = np.linalg.lstsq(basis * sw[:, None], w * sw, rcond=None)
    return float(a), float(k), float(np.sum(mu_w * (basis @ (a, k) - w) ** 2))


def hg_as_power_lobe(g: float) -> tuple[float, float, float, float]:
    """The fitted colour lobe 4π·p_HG(θ, g) (`rtfit.realtime.phase`, mean 1 over the sphere) as
    a + k·max(cos θ, 0)^n, Unreal's constant plus directional inscattering: (a, k, n, relative RMS error
    over the sphere). n from `LOBE_EXPONENTS`, (a, k) by linear least squares for each."""
    mu, mu_w = _nodes()
    w = 4.0 * math.pi * np.asarray(hg_phase_kernel(NUMPY_OPS, mu, float(g)), dtype=np.float64)
    # every n at once by the 2 × 2 normal equations (the choice of n), then that n's least squares itself
    f = _powers()
    s1, sf, sff = float(np.sum(mu_w)), f @ mu_w, (f * f) @ mu_w
    sy, sfy = float(mu_w @ w), f @ (mu_w * w)
    det = s1 * sff - sf * sf
    a_n, k_n = (sff * sy - sf * sfy) / det, (s1 * sfy - sf * sy) / det
    errs = ((a_n[:, None] + k_n[:, None] * f - w) ** 2) @ mu_w
    n = float(LOBE_EXPONENTS[int(np.argmin(errs))])
    a, k, err = _lobe_fit(w, n)
    return a, k, n, math.sqrt(err / float(np.sum(mu_w * w**2)))


@functools.cache
def _powers() -> np.ndarray:
    """max(μ, 0)^n at the quadrature nodes for every n of `LOBE_EXPONENTS` (600 × 512), made once."""
    return np.maximum(_nodes()[0], 0.0)[None, :] ** LOBE_EXPONENTS[:, None]


# ------------------------------------------------------------------------------------------ the files
def is_fog(m: MethodLike) -> bool:
    """Whether ``m`` is a height fog: its parameters hold ``b`` and ``c`` in 1/m."""
    p = m.parameters
    return all(k in p and p[k].unit == "1/m" for k in ("b", "c"))


def _base(m: MethodLike, engine: Engine, base: float | None) -> float:
    if base is not None or not engine.base_from_domain:
        return float(base or 0.0)
    lows = [m.domain[k].lower for k in ("z0", "z1") if k in m.domain]
    return float(min(lows)) if lows else 0.0


def convert_method(m: MethodLike, engine: Engine, base: float | None = None) -> Preset:
    """One fitted fog method (``b``, ``c`` in 1/m; optional C₀ = r0, g0, b0) in ``engine``'s properties."""
    p = m.parameters
    b, c = float(p["b"].value), float(p["c"].value)
    if not (b > 0.0 and c > 0.0 and math.isfinite(b) and math.isfinite(c)):
        raise ConvertError(f"{m.id}: b = {b}, c = {c}: the engines' height fog needs b > 0 and c > 0")
    at = _base(m, engine, base)
    colour = tuple(float(p[k].value) for k in _COLOUR) if all(k in p for k in _COLOUR) else None
    lobe = tuple(float(p[k].value) for k in _LOBE) if all(k in p for k in _LOBE) else None
    if engine.name == "unreal" and lobe is not None and colour is not None:
        a, k, n, rel = hg_as_power_lobe(lobe[3])
        colour = tuple(c0 + a * c1 for c0, c1 in zip(colour, lobe[:3], strict=True))
        values = engine.to_engine(b, c, at, colour)
        values |= {
            "DirectionalInscatteringColor": tuple(k * c1 for c1 in lobe[:3]),
            "DirectionalInscatteringExponent": n,
            "DirectionalInscatteringStartDistance": 0.0,
        }
        lost = [
            f"the phase lobe's shape: 4π·p_HG(θ, g = {lobe[3]:.3g}) as {a:.4g} + {k:.4g}·"
            f"max(cos θ, 0)^{n:.3g} (relative RMS error over the sphere {rel:.2g}); "
            f"FogInscatteringColor holds C₀ + {a:.4g}·C₁",
            *engine.lost[1:],
        ]
        return _preset(engine, m, at, values, lost, p, colour_kept=True)
    values = engine.to_engine(b, c, at, colour if engine.colour else None)
    lost = list(engine.lost)
    if not engine.colour and colour is not None:
        lost.insert(0, f"the fitted colour C₀ = ({', '.join(f'{x:.4g}' for x in colour)}) W/m²/sr")
    if any(k in p for k in _LOBE):
        lobe = ", ".join(f"{k} = {float(p[k].value):.4g}" for k in _LOBE if k in p)
        lost.insert(0, f"the fitted phase lobe ({lobe})")
    return _preset(engine, m, at, values, lost, p)


def _preset(engine: Engine, m: MethodLike, at: float, values: dict, lost, p, colour_kept: bool = False):
    kept = [k for k in ("b", "c", *_COLOUR, *(_LOBE if colour_kept else ())) if k in p]
    return make_preset(engine.name, m, at, values, engine.units, lost, {k: float(p[k].value) for k in kept})


def make_preset(
    engine: str, m: MethodLike, at: float, values: Mapping, units: Mapping[str, str], lost, fitted
):
    """The `Preset` of method ``m``: ``values`` {property: value} with their ``units`` (missing: "1")."""
    return Preset(
        engine=engine,
        method=m.id,
        case=m.case,
        base_height_m=float(at),
        fitted=dict(fitted),
        values=[EngineValue(k, plain_value(v), units.get(k, "1")) for k, v in values.items()],
        lost=list(dict.fromkeys(lost)),
    )
