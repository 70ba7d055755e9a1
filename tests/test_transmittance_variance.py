"""The ratio tracker's variance target (`rtfit.reference.medium_transmittance.variance_exponents`) and the
audit's exact-row checks, which judge only the rays within it (`AuditReference.unchecked`)."""

from __future__ import annotations

import numpy as np
import pytest

from rtfit.experiments.audit_results import MethodOutcome, _checks
from rtfit.experiments.audit_setup import AuditReference
from rtfit.realtime.methods import Method


def test_the_variance_exponent_is_the_trackers_bound_on_a_homogeneous_segment(mi):
    """On a homogeneous medium of σt = m over a segment of length L (the caller's near and far: such a medium
    is unbounded), the bound m²L/σ̄ with σ̄·L = max(mL, 4, min((mL)²/0.25, 1024)) (the module's rule, here
    written out by hand): 0.0625 at mL = 0.5, the target 0.25 at mL = 8 and 16, 1.5625 at mL = 40, and mL
    itself at mL = 2000 (σ̄ = m); 0 for a ray that crosses nothing (near = far)."""
    from rtfit.reference.medium_transmittance import VARIANCE_EXPONENT, variance_exponents

    sigma_t = 5.0
    medium = mi.load_dict({"type": "homogeneous", "sigma_t": sigma_t, "albedo": 0.5})
    ml = np.array([0.5, 8.0, 16.0, 40.0, 2000.0])
    far = 1.0 + ml / sigma_t
    dirs = np.tile([0.0, 0.0, 1.0], (len(ml) + 1, 1))
    near = np.append(np.ones(len(ml)), 3.0)
    got = variance_exponents(mi, medium, np.zeros(3), dirs, np.append(far, 3.0), min_distance=near)
    want = ml**2 / np.maximum(np.maximum(ml, 4.0), np.minimum(ml**2 / VARIANCE_EXPONENT, 1024.0))
    np.testing.assert_allclose(got[:-1], want, rtol=1e-5)
    np.testing.assert_allclose(want, [0.0625, 0.25, 0.25, 1.5625, 2000.0])
    assert got[-1] == 0.0


def _case_with(unchecked):
    """A 1 × 40 case whose exact row equals the reference on its first 20 pixels (z = 0) and sits 10
    standard errors off on the last 20; ``unchecked`` flags pixels the checks must not judge."""
    from rtfit.experiments.audit_family import FamilyCase

    mask = np.ones((1, 40), bool)
    mean = np.full((1, 40, 3), 0.5)
    stderr = np.full((1, 40, 3), 0.01)
    ref = AuditReference(mean=mean, stderr=stderr, spp=32, passes=1, passes_rendered=1, cache_key="k",
                         cache_path="p", seconds=0.0, quantity="q", integrator="i", integrator_reason="r",
                         mask=mask, unchecked=unchecked)  # fmt: skip
    rng = np.random.default_rng(0)
    image = mean + stderr * rng.standard_normal(mean.shape)  # the first 20: z-scores of a standard normal
    image[0, 20:] = mean[0, 20:] + 10 * stderr[0, 20:]
    method = Method("exact", "exact", lambda ops, x: x, exact=True)
    case = FamilyCase(id="c", label="c", reference=ref, mask=mask)
    row = MethodOutcome("c", "exact", method, "exact", image, None, {})
    return [(None, None, case)], {"c": {"exact": row}}


@pytest.mark.parametrize("flag_tail", [True, False])
def test_the_exact_rows_checks_leave_out_the_unchecked_pixels(flag_tail):
    unchecked = None
    if flag_tail:
        unchecked = np.zeros((1, 40), bool)
        unchecked[0, 20:] = True
    checks = _checks(*_case_with(unchecked))
    assert checks and all(c["passed"] for c in checks) == flag_tail, checks
    if flag_tail:
        assert all("60 elements" in c["name"] for c in checks if "elements" in c["name"])  # 20 pixels × 3


def test_a_case_with_every_pixel_unchecked_is_reported_not_judged():
    checks = _checks(*_case_with(np.ones((1, 40), bool)))
    assert len(checks) == 1 and checks[0]["passed"] and "not judged" in checks[0]["expected"]
