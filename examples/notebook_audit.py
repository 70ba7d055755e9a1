"""A notebook's cells as a script (issue 37 §1): audit a scene built with ``mi.load_dict``'s dict, read a
metric with its noise floor, display the inline summary.

Run it: ``python examples/notebook_audit.py [CACHE_DIR]`` (seconds: 16 × 16 pixels, 8 samples per pixel).
In Jupyter, each ``# %%`` block is one cell and the last line of a cell (``r``) shows the summary table
(`AuditResult._repr_html_`); here `display` prints the same HTML. ``tests/test_audit_api.py`` runs it.
"""

# %% The scene, as a notebook writes it for mi.load_dict
import sys

import mitsuba as mi

import rtfit

mi.set_variant("scalar_rgb")  # the notebook's own variant: the audit leaves it as it was
T = mi.ScalarTransform4f
scene = {
    "type": "scene",
    "integrator": {"type": "path"},
    "sensor": {
        "type": "perspective",
        "fov": 40,
        "to_world": T().look_at(origin=[0, 1, 4], target=[0, 0, 0], up=[0, 1, 0]),
        "film": {"type": "hdrfilm", "width": 16, "height": 16},
    },
    "light": {"type": "point", "position": [1, 3, 2], "intensity": {"type": "rgb", "value": [10, 10, 10]}},
    "ball": {
        "type": "sphere",
        "radius": 0.5,
        "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.6, 0.5, 0.4]}},
    },
    "floor": {
        "type": "rectangle",
        "to_world": T().translate([0, -0.5, 0]).rotate([1, 0, 0], -90).scale(3),
        "bsdf": {"type": "diffuse"},
    },
}
image = mi.render(mi.load_dict(scene), spp=4)  # the notebook's own render of the same dict, untouched

# %% The audit of the diffuse family on that dict (few samples: a quick look, not a ranking)
cache = sys.argv[1] if len(sys.argv) > 1 else None
r = rtfit.audit(scene, "diffuse", spp=8, pass_spp=4, fit=False, cache=cache, metrics=("rmse", "mae"))
print([c.id for c in r.cases])

# %% A metric with its noise floor
m = r.metrics("light0-unshadowed", "half-lambert")["rmse"]
verdict = "resolved" if m.resolved else "within the reference's noise"
print(f"half-Lambert RMSE {m.value:.4g} W/m² (noise floor {m.noise_floor:.2g}): {verdict}")
exact = r.metrics("light0-unshadowed", "lambert")["rmse"]
print(
    f"Lambert RMSE {exact.value:.2g} W/m² (noise floor {exact.noise_floor:.2g}, resolved: {exact.resolved})"
)


# %% The inline summary (in Jupyter: just `r` as the cell's last line)
def display(obj) -> None:
    print(obj._repr_html_())


display(r)
assert mi.variant() == "scalar_rgb"
