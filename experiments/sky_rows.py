r"""The Nishita sky family's audit rows, shared by its two audit roles (`rtfit.experiments.audit_nishita_sky`:
an rtfit sky file's atmosphere; `rtfit.experiments.audit_sky_emitter`: a Mitsuba sunsky) and its experiment.

`nishita_rows`: every RGB method of `rtfit.realtime.nishita_sky.METHODS` with a given atmosphere and viewer
altitude, each on the kernel inputs of its own texture setting; `near_sun`: the pixels the sun's disc covers,
left out of every sky comparison (the disc is a separate term).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from rtfit.realtime.methods import Input, Method
from rtfit.realtime.nishita_sky import METHODS, AtmosphereParams, build_sky, sky_kernel_inputs
from rtfit.reference.variants import backend_of

from .audit_family import Precompute

__all__ = [
    "SETTING_INPUTS",
    "SPECTRAL_NOTE",
    "TEXTURE_UNCOSTED",
    "near_sun",
    "nishita_rows",
    "setting_method",
    "texture_precomputes",
]


def texture_precomputes(
    atmosphere: AtmosphereParams, elev: float, alt: float, rows: dict[str, Method], variant: str
) -> dict[str, Precompute]:
    """Each row's precompute (`FamilyCase.precompute`): its sky texture built once (`build_sky` with the
    atmosphere, sun elevation ``elev`` degrees, viewer altitude ``alt`` m and the row's texture setting, on
    ``variant``'s Dr.Jit backend), paid again when the sun or the atmosphere changes; rows of one setting
    share one (timed once). The per-pixel lookup stays uncosted here (`TEXTURE_UNCOSTED`)."""
    backend = backend_of(variant)
    by_setting: dict[tuple, Precompute] = {}
    out = {}
    for rid, m in rows.items():
        s = m.fixed["setting"]
        key = _setting_key(m)
        if key not in by_setting:
            kw = s.build_keywords()

            def run(kw=kw):
                sky = build_sky(atmosphere, elev, alt, backend=backend, **kw)
                return sky.rayleigh, sky.mie

            what = f"the sky texture built: {s.layers} layers, {s.width}×{s.height} texels"
            by_setting[key] = Precompute(run, "light", what)
        out[rid] = by_setting[key]
    return out


def near_sun(dirs, elev: float, degrees: float = 1.0) -> np.ndarray:
    """Pixels within ``degrees`` of the sun (excluded from the metrics: the sun disc is a separate term).
    ``dirs`` (…, 3): unit directions in the sky's frame (+Z up, the sun at azimuth 0 and elevation ``elev``
    degrees)."""
    e = math.radians(elev)
    s_dir = np.array([math.cos(e), 0.0, math.sin(e)])
    return np.degrees(np.arccos(np.clip(dirs @ s_dir, -1, 1))) < degrees


SPECTRAL_NOTE = (
    "nishita-spectral is not a row: its kernel text is the RGB one (the spectral sky is built over its "
    "wavelengths by SkySetting.radiance, outside the method's kernel), so it would repeat nishita-seed"
)
"""Why the spectral variant is left out of the audit's rows."""

TEXTURE_UNCOSTED = (
    "the kernel rebuilds the whole sky texture (n layers, W×H texels, 2n + 4 path steps each) on every call, "
    "so that a fit can change its parameters: timed per pixel it would divide one texture build by this "
    "image's pixel count. An engine builds the texture once per sun or atmosphere change and looks it up per "
    "pixel: the texture's build is its precompute (Precompute ms), the lookup's ns/pixel is timed by "
    "`rtfit run nishita-sky`'s study"
)
"""Why the Nishita rows have no cost per pixel (`FamilyCase.uncosted`): timing the kernel took 44 s of a
52-s evaluation of one 32×16 sky file (2 CPU cores), for a number that was not a per-pixel cost (issue 33)."""

SETTING_INPUTS = ("texel_mu", "texel_nu", "tau_r", "tau_m")
"""The kernel inputs that depend on a method's texture setting (its texel grid and sun table)."""


def _setting_key(method: Method) -> tuple:
    s = method.fixed["setting"]
    return (s.width, s.height, s.layers, s.table_size, s.mapping)


def setting_method(method: Method, suffix: str, **fixed) -> Method:
    """``method`` with ``fixed`` keywords replaced (the file's atmosphere, the viewer's altitude) and, for a
    non-empty ``suffix``, its setting-dependent inputs (`SETTING_INPUTS`) renamed ``name + suffix``, so that
    methods of different texture settings read their own tables on one case; the kernel is the method's own
    (the names are mapped back)."""
    back = {f"{n}{suffix}": n for n in SETTING_INPUTS} if suffix else {}
    inner = method.kernel

    def kernel(ops, **kw):
        return inner(ops, **{back.get(k, k): v for k, v in kw.items()})

    kernel.__qualname__ = kernel.__name__ = f"{getattr(inner, '__name__', 'kernel')}{suffix}"
    inputs = tuple(
        Input(i.name + suffix, i.unit, i.description, i.domain) if i.name in SETTING_INPUTS and suffix else i
        for i in method.inputs
    )
    return dataclasses.replace(method, kernel=kernel, inputs=inputs, fixed={**method.fixed, **fixed})


def nishita_rows(
    atmosphere: AtmosphereParams, elev: float, d: np.ndarray, alt: float
) -> tuple[dict, dict[str, Method]]:
    """The inputs and rows of a sky case: every RGB method of `METHODS` (not the spectral one,
    `SPECTRAL_NOTE`) with ``atmosphere`` and the viewer altitude ``alt`` (m) in its fixed keywords, on the
    kernel inputs of its own texture setting (`sky_kernel_inputs` for the unit directions ``d`` (N, 3) in the
    sky's frame: +Z up, the sun at azimuth 0 and elevation ``elev`` degrees; a setting other than the first
    gets its inputs under names of its own, `setting_method`), plus the user approximations' inputs sx, sy,
    sz (the unit direction to the sun) and altitude."""
    n = len(d)
    el = math.radians(elev)
    inputs: dict = {
        "sx": np.full(n, math.cos(el)),
        "sy": np.zeros(n),
        "sz": np.full(n, math.sin(el)),
        "altitude": np.full(n, alt),
    }
    groups: dict[tuple, str] = {}
    rows: dict[str, Method] = {}
    for mid, m in METHODS.items():
        if m.fixed["setting"].wavelengths:
            continue  # its kernel text is the RGB one: the spectral sky is built outside it (SPECTRAL_NOTE)
        key = _setting_key(m)
        if key not in groups:
            suffix = "" if not groups else f"_s{len(groups)}"
            groups[key] = suffix
            values = sky_kernel_inputs(atmosphere, elev, d, m.fixed["setting"], alt)
            inputs.update({(k + suffix if k in SETTING_INPUTS else k): v for k, v in values.items()})
        rows[mid] = setting_method(m, groups[key], atmosphere=atmosphere, altitude_m=alt)
    return inputs, rows
