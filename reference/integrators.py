"""The integrator rule: the cheapest Mitsuba integrator that is still exact for a scene.

A reference must converge to the physically exact value of the quantity the scene declares
(``[reference] transport``), and spend nothing on light paths that cannot carry energy. The rule,
applied in this order:

1. **Media present** → ``volpathmis``. It is the only Mitsuba integrator that is unbiased with
   spectrally varying extinction (``volpath`` is biased/heavy-tailed there, Mitsuba issues #1387 and
   #1846), and surfaces-only integrators ignore media. ``transport = "direct"`` means single
   scattering: ``max_depth = 2``; ``"global"``: the scene's ``max_depth`` or -1 (unbounded).
2. **Direct transport requested** → ``direct``: emitter and BSDF sampling with MIS, exact for light
   that reaches a surface straight from the emitters (what most real-time lighting terms model).
3. **Global transport, but no path can bounce more than once** → ``direct`` again. That holds when
   no reflective surface can see another reflective surface: at most one reflective shape, and that
   shape is convex (a convex surface cannot see itself), or every surface is black. Emitter geometry
   is always black (lights do not reflect in rtfit scenes).
4. Otherwise → ``path`` with the scene's ``max_depth`` (default -1: unbounded; Russian roulette
   keeps it unbiased).

This module is pure Python (no Mitsuba), so the rule is tested on its own.
"""

from __future__ import annotations

from dataclasses import dataclass

from rtfit.scenes.model import Scene

SINGLE_BOUNCE_DEPTH = 2  # Mitsuba counts: 1 = emitters seen directly, 2 = direct illumination


@dataclass(frozen=True)
class IntegratorChoice:
    """A Mitsuba integrator type, its ``max_depth`` (None: not a parameter of it) and why."""

    type: str
    max_depth: int | None
    reason: str

    def to_dict(self) -> dict:
        return {"type": self.type, "max_depth": self.max_depth, "reason": self.reason}

    def mitsuba_dict(self) -> dict:
        d: dict = {"type": self.type}
        if self.max_depth is not None:
            d["max_depth"] = self.max_depth
        return d


def _reflective(shape) -> bool:
    material = getattr(shape, "material", None)
    if shape.kind == "mitsuba_xml":
        # A user's file may hold any BSDF; assume it reflects unless overridden with black.
        material = shape.override_material
        return material is None or any(c > 0.0 for c in material.reflectance)
    return material is not None and any(c > 0.0 for c in material.reflectance)


def can_interreflect(scene: Scene) -> bool:
    """True if light may bounce between (or within) reflective surfaces of the scene."""
    reflective = [s for s in scene.shapes if _reflective(s)]
    if len(reflective) >= 2:
        return True
    if len(reflective) == 1:
        return not reflective[0].convex
    return False


def choose_integrator(scene: Scene) -> IntegratorChoice:
    """Apply the rule in the module docstring to ``scene``."""
    settings = scene.reference
    if scene.media:
        if settings.transport == "direct":
            return IntegratorChoice(
                "volpathmis", SINGLE_BOUNCE_DEPTH, "media present, single scattering requested"
            )
        depth = settings.max_depth if settings.max_depth is not None else -1
        return IntegratorChoice(
            "volpathmis", depth, "media present: volpathmis is unbiased with chromatic extinction"
        )
    if settings.transport == "direct":
        return IntegratorChoice("direct", None, "direct transport requested")
    if not can_interreflect(scene):
        return IntegratorChoice(
            "direct", None, "global transport, but no reflective surface can see another: one bounce is exact"
        )
    depth = settings.max_depth if settings.max_depth is not None else -1
    return IntegratorChoice("path", depth, "global transport with interreflections")
