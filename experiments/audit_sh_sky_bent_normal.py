"""The ``sh-sky-bent-normal`` family on a scene's sky (`rtfit audit`, and ``rtfit run sh-sky-bent-normal`` on
its shipped scene): the sky's SH read along the bent normal, as the seed lights its terrain (000:425-432),
against the sky's irradiance with the scene's occlusion.

Role (its ``rules``): ``sky ambient (SH at the bent normal)`` — every environment of the scene (a Mitsuba XML
``envmap``, ``constant`` or ``sunsky`` emitter, or an rtfit TOML ``constant_env``, ``envmap`` or ``sunsky``
light) together with geometry that can occlude it: the same parts the sky-occlusion role needs.

One case ``shsky<i>`` per environment, on the visible surface pixels (`rtfit.experiments.audit_sky`: the
reference and the bake are shared with the sdf-occlusion sky role and ambient-aperture's fill, one set of
passes per environment):

* **reference**: E = ∫ V(ω) L_sky(ω) max(n·ω, 0) dω (W/m², RGB) with the scene's shapes as occluders, by
  Mitsuba's emitter sampling and the cosine hemisphere (balance heuristic) with shadow rays, in independent
  passes with per-pixel standard errors (a sunsky's sky without its sun: the sun is the sphere-light roles');
* **inputs** (one mapping: the rows return (R, G, B)): n (the G-buffer's unit normal), the bake's bent
  normal b, AO V (cosine-weighted unoccluded fraction) and aperture r_a = acos(1 − V_u), all from unbounded
  uniform ray casts of their own seed; ``coeffs``, the sky's SH L2 projection (27 floats, channel-major, as
  the irradiance-bases family bakes it from the emitter), a table;
* **rows**: `rtfit.realtime.sh_sky_bent_normal.METHODS` — the seed's π·L_SH(b)·V, the SH irradiance at b
  and at n times V (each with the scale s and the AO exponent p fitted to the scene), and the SH irradiance
  through the visible cone (s fitted). No row is exact: all read the bake and the SH projection.

A user approximation of ``sky_irradiance_sh`` gets the same inputs (``g.normal``, ``g.bent_normal``,
``g.ao``, ``g.aperture``, ``g.coeffs``, and the point ``g.point``) and returns (R, G, B).
"""

from __future__ import annotations

from rtfit.realtime.arrays import xyz_columns
from rtfit.realtime.sh_sky_bent_normal import METHODS

from .audit import Applicability, Rule
from .audit_family import AuditFamily, FamilyCase
from .audit_setup import AuditSetup
from .audit_sky import occluded_sky
from .shipped import Sizes

__all__ = ["FAMILY", "SCENES", "sh_sky_cases"]

SCENES = (
    Sizes(full=(64, 64, 256), quick=(24, 24, 32)).scene(
        "sh_sky_bent_normal_blocks.xml",
        "two boxes, a sphere and a wall on a grey ground plane under Mitsuba's sunsky (sun 30° up; its sky "
        "alone is audited): creases, contact shadows and open ground",
    ),
)
"""The scene ``rtfit run sh-sky-bent-normal`` audits (scenes/library/)."""


def sh_sky_cases(setup: AuditSetup, app: Applicability) -> list[FamilyCase]:
    """One case per environment: the rows on the bake and the sky's SH against the occluded sky irradiance
    (module docstring)."""
    sky = occluded_sky(setup, app, "sh-sky-bent-normal")
    inputs = {
        **xyz_columns("n", sky.normals),
        **xyz_columns("b", sky.bent),
        "ao": sky.visibility,
        "aperture": sky.aperture,
        "coeffs": sky.sh,
        **xyz_columns("p", sky.points),
    }
    methods = {rid: METHODS[rid] for rid in app.methods}
    return [
        FamilyCase(
            id=f"shsky{app.source}",
            label=f"{app.part}: sky irradiance with visibility, the sky's SH at the bent normal",
            reference=sky.reference,
            channel_inputs=(inputs,),
            parameters={
                "environment": app.part,
                "kind": sky.kind,
                "bake_rays_per_point": sky.bake_spp,
                "mean_ao": float(sky.visibility.mean()),
                "mean_aperture_rad": float(sky.aperture.mean()),
                "pixels": int(setup.mask.sum()),
            },
            units="W/m²",
            notes=(
                *sky.notes,
                "seed row: π·L_SH(b) is the irradiance-equivalent of the seed's radiance lookup (an engine "
                "multiplies L by the albedo ρ: ρL = ρ(πL)/π); the AO factor is the issue's reading",
            ),
            methods=methods,
        )
    ]


FAMILY = AuditFamily(
    name="sh-sky-bent-normal",
    quantity="sky_irradiance_sh",
    cases=sh_sky_cases,
    describe=(
        "Per environment with occluding geometry: the sky's irradiance with visibility "
        "E = ∫ L_env V (n·ω) dω (W/m², RGB; a sunsky's sky without its sun) at each visible point, by "
        "Mitsuba's emitter sampling and the cosine hemisphere (balance heuristic) with shadow rays against "
        "the scene's shapes, in "
        "independent passes with per-pixel standard errors — against the seed's ambient (the sky's SH L2 "
        "radiance looked up along the bent normal, × AO), the SH L2 irradiance at the bent normal and at the "
        "normal × AO, and the SH irradiance through the visible cone about the bent normal. The bent normal, "
        "AO and cone come from unbounded ray casts (what an engine bakes); the SH from the emitter's "
        "projection. The scale and AO exponent are fitted per scene."
    ),
    formats=("mitsuba-xml", "rtfit-toml"),
    rules=(
        Rule(
            "sh-sky-bent-normal",
            "sky ambient (SH at the bent normal)",
            ("environment", "geometry"),
            "{part} lights the scene's surfaces, occluded by {with_}: an engine reads its SH along the bent "
            "normal times AO",
            "sky irradiance with visibility at the visible points (the environment's direct light, shadowed; "
            "a sunsky's sky alone)",
            "the environment alone: emitter + cosine sampling (MIS) with shadow rays against the scene's "
            "shapes; the bent normal, AO and cone by unbounded ray casts",
            supplies=frozenset({"bx", "by", "bz", "ao"}),  # the visibility bake beside the reference
        ),
    ),
)
