r"""The ``nishita-sky`` family in `rtfit audit`: the sky of an rtfit sky file along its camera's sky pixels.

An rtfit sky file (``format = "rtfit.sky/1"``, `rtfit.reference.nishita_sky.load_atmosphere_scene`: planet,
spherical-shell Rayleigh + Mie atmosphere, sun, viewer altitude) has no camera of its own; the audit's camera
is the azimuth × elevation panorama of the upper hemisphere the Nishita-sky experiment renders
(`rtfit.experiments.audit_run.sky_view`, `hemisphere_directions`: the sun at azimuth 0, every pixel a sky
pixel; ``--width``/``--height`` set its size). One case, ``sky``:

* reference: the sky radiance L (W/m²/sr per the file's solar irradiance, RGB: the file's three
  wavelengths) along each pixel's direction from the viewer, single and multiple scattering with the ground
  bounce (`rtfit.reference.nishita_sky.render_sky`, ``rtfit_skypath`` in the shell atmosphere, ``max_depth``
  −1, its own pass cache), the experiment's multiple-scattering reference; pixels within 1° of the sun are
  left out (`rtfit.experiments.nishita_sky.near_sun`: the disc is a separate term);
* rows: every RGB method of `rtfit.realtime.nishita_sky.METHODS` (the seed setting, the fine setting, the
  fitted artist parameters; not the spectral variant, `SPECTRAL_NOTE`) with the file's atmosphere and
  viewer altitude in its fixed keywords (`atmosphere_params_of`), each on the kernel inputs of its own
  texture setting (`sky_kernel_inputs`: texel directions and sun optical-depth tables; a setting other than
  the seed's gets those inputs under names of its own, `setting_method`); ``nishita-fitted``'s artist
  parameters (Rayleigh scale, Mie density scale, Mie g, isotropic ambient) are fitted to this sky through
  the JAX run
  of the same kernel; and your approximations of ``sky_radiance`` (inputs dx, dy, dz: the unit view
  direction; sx, sy, sz: the unit direction to the sun; altitude: the viewer's, m).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from rtfit.realtime.methods import Input, Method
from rtfit.realtime.nishita_sky import METHODS, sky_kernel_inputs
from rtfit.reference.nishita_sky import render_sky

from .audit import Applicability
from .audit_family import AuditError, AuditFamily, AuditReference, AuditSetup, FamilyCase, masked_image
from .nishita_sky import atmosphere_params_of, near_sun

__all__ = ["FAMILY", "SETTING_INPUTS", "SPECTRAL_NOTE", "setting_method", "sky_cases"]

SPECTRAL_NOTE = (
    "nishita-spectral is not a row: its kernel text is the RGB one (the spectral sky is built over its "
    "wavelengths by SkySetting.radiance, outside the method's kernel), so it would repeat nishita-seed"
)
"""Why the spectral variant is left out of the audit's rows."""

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


def sky_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """The sky case of the file's atmosphere (module docstring)."""
    spec = setup.source
    if spec is None or not hasattr(spec, "sun_elevation_deg"):
        raise AuditError(
            f"nishita-sky: {app.part}: the audit reads the sky from rtfit sky files (rtfit.sky/1)"
        )
    elev = float(spec.sun_elevation_deg)
    alt = float(spec.viewer_altitude_m)
    dirs = setup.gbuffer.view_dir.astype(np.float64)
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    mask = ~setup.gbuffer.mask & ~near_sun(dirs, elev)
    if not mask.any():
        raise AuditError("nishita-sky: every pixel of the panorama lies within 1° of the sun")
    d = dirs[mask]
    n = len(d)
    ref = render_sky(
        spec, d, setup.spp, setup.pass_spp, setup.seed, setup.variant, -1, cache_dir=setup.cache_root
    )
    atmosphere = atmosphere_params_of(spec)
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
    reference = AuditReference(
        mean=masked_image(mask, ref["mean"]),
        stderr=masked_image(mask, ref["stderr"]),
        spp=int(ref["spp"]),
        passes=int(ref["passes"]),
        passes_rendered=int(ref["passes"]),
        cache_key=str(ref["cache_key"]),
        cache_path=str(setup.cache_root),
        seconds=float(ref["seconds"]),
        quantity="sky radiance along the panorama's directions, single + multiple scattering (RGB)",
        integrator="rtfit_skypath (max_depth −1) in the spherical-shell atmosphere",
        integrator_reason="media with chromatic extinction; all scattering orders and the ground bounce",
    )
    return [
        FamilyCase(
            id="sky",
            label=f"sky, sun {elev:g}°, viewer {alt:g} m",
            reference=reference,
            mask=mask,
            channel_inputs=(inputs,),
            parameters={
                "sun_elevation_deg": elev,
                "viewer_altitude_m": alt,
                "pixels": int(mask.sum()),
                "panorama": [int(mask.shape[1]), int(mask.shape[0])],
            },
            units="W/m²/sr",
            notes=(
                "pixels within 1° of the sun are left out (the sun disc is a separate term)",
                SPECTRAL_NOTE,
            ),
            methods=rows,
            quantity="sky_radiance",
        )
    ]


FAMILY = AuditFamily(
    name="nishita-sky",
    quantity="sky_radiance",
    formats=("rtfit-sky",),
    cases=sky_cases,
    describe=(
        "The sky radiance (RGB) of the file's atmosphere along the directions of an azimuth × elevation "
        "panorama of the upper hemisphere (sun at azimuth 0), seen from the file's viewer: Mitsuba's "
        "rtfit_skypath in the spherical-shell Rayleigh + Mie atmosphere with all scattering orders (the "
        "Nishita-sky experiment's multiple-scattering reference), pixels within 1° of the sun left out. "
        "Every Nishita method runs with the file's atmosphere and altitude on its own texture setting; the "
        "fitted method's artist parameters are fitted to this sky."
    ),
)
