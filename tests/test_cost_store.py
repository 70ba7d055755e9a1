"""Costs kept across runs (`rtfit.experiments.cost_store`, issue 33): the key follows the content of what a
cost is measured on and nothing else, the store gives back what it kept (and nothing it cannot read), and a
second audit with the same cache reports the first audit's costs, saying so, without timing them again."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import rtfit
from rtfit.experiments import cost_store
from rtfit.experiments.cost_store import COST_NOTE, CostStore, cost_key
from rtfit.realtime.diffuse import METHODS
from rtfit.realtime.pcf_soft_shadows import ShadowMap

LAMBERT = METHODS["lambert"]


def _inputs(cos=None):
    cos = np.linspace(-1.0, 1.0, 64) if cos is None else cos
    return {"cos_theta": cos, "irradiance": np.full(64, 2.0)}


def _key(inputs, method=LAMBERT, size=1 << 10, device="CPU"):
    return cost_key(method, inputs, "llvm", size, device)


def test_the_key_follows_the_inputs_content_and_the_machine():
    base = _key(_inputs())
    assert base is not None and base == _key(_inputs())  # the same content, other arrays: the same key
    nudged = np.linspace(-1.0, 1.0, 64)
    nudged[7] = np.nextafter(nudged[7], 2.0)  # one ulp
    assert _key(_inputs(nudged)) != base
    assert _key(_inputs(np.linspace(-1.0, 1.0, 64).astype(np.float32))) != base  # another dtype
    assert _key(_inputs(), size=1 << 11) != base
    assert _key(_inputs(), device="GPU") != base
    assert _key(_inputs(), method=METHODS["half-lambert"]) != base


def test_a_cases_kept_digests_give_the_keys_hashed_anew(monkeypatch):
    """`cost_key` with a case's ``digests``: the same key as each array hashed anew, every array hashed once
    for two methods (counted on the hash's constructor), another array of the same content the same key."""
    import rtfit.experiments.cost_store as store

    inputs = _inputs()
    fresh = [_key(inputs), cost_key(METHODS["half-lambert"], inputs, "llvm", 1 << 10, "CPU")]
    made = []
    sha256 = store.hashlib.sha256
    monkeypatch.setattr(store.hashlib, "sha256", lambda *a: made.append(1) or sha256(*a))
    digests: dict = {}
    kept = [cost_key(m, inputs, "llvm", 1 << 10, "CPU", digests) for m in (LAMBERT, METHODS["half-lambert"])]
    assert kept == fresh
    assert len(digests) == 2 and len(made) == 2 + 2  # two arrays once, and each method's own key
    assert cost_key(LAMBERT, _inputs(), "llvm", 1 << 10, "CPU", digests) == fresh[0]


def test_a_samplers_caches_are_not_its_content_but_its_arrays_are():
    """A shadow map's per-backend tables and kept NumPy runs (dicts declared compare=False) fill as it is
    used: its key stays; a depth changed changes it."""

    def smap(depth):
        return ShadowMap(depth=depth, near=1.0)

    depth = np.linspace(1.0, 2.0, 16).reshape(4, 4)
    m = smap(depth.copy())
    before = cost_key(LAMBERT, {**_inputs(), "irradiance": m}, "llvm", 1024, "CPU")
    m._tables[("x",)] = np.zeros(3)
    m._kept["y"] = np.ones(5)
    assert cost_key(LAMBERT, {**_inputs(), "irradiance": m}, "llvm", 1024, "CPU") == before
    other = depth.copy()
    other[0, 0] += 0.5
    assert cost_key(LAMBERT, {**_inputs(), "irradiance": smap(other)}, "llvm", 1024, "CPU") != before


def test_what_cannot_be_told_by_content_has_no_key():
    """A callable from outside rtfit (its text is not in the source digest) and an object holding nothing
    readable give no key: such a cost is measured every run."""

    class Opaque:
        def __init__(self):
            self.handle = object()

    @dataclasses.dataclass
    class Empty:
        cache: dict = dataclasses.field(default_factory=dict, compare=False)

    assert _key({**_inputs(), "irradiance": lambda x: x}) is None
    assert _key({**_inputs(), "irradiance": Opaque()}) is None
    assert _key({**_inputs(), "irradiance": Empty()}) is None


def test_the_store_gives_back_what_it_kept_and_measures_what_it_cannot_read(tmp_path):
    store = CostStore(tmp_path, "CPU")
    calls = []

    def measure():
        calls.append(1)
        return {"ns_per_pixel": 1.5, "pixels_per_second": 1e9 / 1.5, "elements": 1024, "repeats": 6,
                "backend": "llvm"}  # fmt: skip

    key = store.key(LAMBERT, _inputs(), "llvm", 1024)
    first = store.cost(key, measure)
    again = store.cost(key, measure)
    assert len(calls) == 1 and again["ns_per_pixel"] == first["ns_per_pixel"] == 1.5
    assert again["note"].startswith(COST_NOTE) and "earlier run" in again["note"]
    (path,) = (tmp_path / "costs").iterdir()
    path.write_text("{ not json")
    assert store.cost(key, measure)["ns_per_pixel"] == 1.5 and len(calls) == 2  # measured again, kept
    assert json.loads(path.read_text())["key"] == key
    assert store.cost(None, measure) and len(calls) == 3  # no key: measured, nothing kept
    assert CostStore(None, "CPU").key(LAMBERT, _inputs(), "llvm", 1024) is None


def test_the_source_digest_is_rtfits_text():
    """Every package's files are read: the digest is stable within a run and is a SHA-256."""
    d = cost_store.source_digest()
    assert len(d) == 64 and d == cost_store.source_digest()


XML = """<scene version="3.0.0">
  <sensor type="perspective">
    <float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0, 1, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="12"/><integer name="height" value="12"/></film>
  </sensor>
  <emitter type="point"><point name="position" value="1, 3, 2"/><rgb name="intensity" value="10, 10, 10"/>
  </emitter>
  <shape type="sphere"><float name="radius" value="0.5"/><bsdf type="diffuse"/></shape>
</scene>
"""


@pytest.mark.slow
def test_a_second_audit_reports_the_first_audits_costs_without_timing_them(tmp_path, monkeypatch):
    """The same scene audited twice into one cache: the second audit times no method (`method_cost` is not
    called) and reports the first's costs, each saying it was kept; another cache measures them again."""
    from rtfit.experiments import audit_cases

    scene = tmp_path / "ball.xml"
    scene.write_text(XML)
    fast = {"cost_elements": 1 << 10, "metrics": ("rmse",), "fit": False, "spp": 4, "pass_spp": 2,
            "approximations": "diffuse"}  # fmt: skip
    first = rtfit.audit(str(scene), cache=tmp_path / "cache", **fast)
    timed = []
    measure = audit_cases.method_cost
    monkeypatch.setattr(audit_cases, "method_cost", lambda *a, **k: timed.append(a[0].id) or measure(*a, **k))
    second = rtfit.audit(str(scene), cache=tmp_path / "cache", **fast)
    assert timed == [] and set(second.costs) == set(first.costs) and first.costs
    for mid, c in second.costs.items():
        assert c["ns_per_pixel"] == first.costs[mid]["ns_per_pixel"] and "earlier run" in c["note"]
    third = rtfit.audit(str(scene), cache=tmp_path / "other", **fast)
    assert sorted(timed) == sorted(first.costs) and all("note" not in c for c in third.costs.values())


def test_a_precompute_timing_is_kept_by_its_methods_key_its_scene_and_its_step(tmp_path):
    """`CostStore.precompute_key` (issue 33, session 33): None without a method key, a reference key or a
    store; another step, trigger, pixel count or reference is another key. `CostStore.precompute` keeps a
    number and gives it back with words saying when it was timed; a step that timed nothing keeps nothing."""
    store = CostStore(tmp_path, "CPU")
    key = store.key(LAMBERT, _inputs(), "llvm", 1024)
    args = ("ref", "bake", "scene", 100)
    k = store.precompute_key(key, *args)
    assert k is not None and store.precompute_key(None, *args) is None
    assert store.precompute_key(key, "", "bake", "scene", 100) is None
    assert CostStore(None, "CPU").precompute_key(key, *args) is None
    others = [("ref2", "bake", "scene", 100), ("ref", "bake 2", "scene", 100), ("ref", "bake", "light", 100),
              ("ref", "bake", "scene", 101)]  # fmt: skip
    assert len({k, *(store.precompute_key(key, *o) for o in others)}) == 5
    calls = []
    assert store.precompute(k, lambda: calls.append(1) or 12.5) == (12.5, "")
    ms, words = store.precompute(k, lambda: calls.append(1) or 99.0)
    assert ms == 12.5 and "earlier run" in words and len(calls) == 1
    k2 = store.precompute_key(key, *others[0])
    assert store.precompute(k2, lambda: None) == (None, "") and store.get(k2) is None
