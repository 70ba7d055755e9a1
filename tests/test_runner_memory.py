"""What a suite hands back between its experiments (issue 33: `rtfit run all --quick` runs every family in
one process, and its peak memory was what earlier families left behind plus the next one's own need).

`runner.forget_memos` empties the ``MEMOS`` of every loaded rtfit module and of nothing else; a memo emptied
is rebuilt on the next call with the same values (the lat-long quadrature's table against the sum over the
grid written here)."""

from __future__ import annotations

import sys
import types

import numpy as np

from rtfit.experiments import runner
from rtfit.fitting import least_squares, method_fit
from rtfit.realtime import sdf_occlusion
from rtfit.reference import latlong_quadrature as lq


def test_forget_memos_empties_the_rtfit_modules_memos_only(monkeypatch):
    planted = types.ModuleType("rtfit.planted_memos")
    vars(planted)["MEMOS"] = ({"a": 1}, [2, 3])
    other = types.ModuleType("planted_elsewhere")
    vars(other)["MEMOS"] = ({"kept": 1},)
    monkeypatch.setitem(sys.modules, planted.__name__, planted)
    monkeypatch.setitem(sys.modules, other.__name__, other)
    runner.forget_memos()
    assert vars(planted)["MEMOS"] == ({}, [])
    assert vars(other)["MEMOS"] == ({"kept": 1},)


def test_the_shared_memos_are_declared():
    """The memos that outlived their experiment in the quick suite are among their modules' ``MEMOS``."""
    declared = {id(m) for mod in (lq, sdf_occlusion, method_fit, least_squares) for m in mod.MEMOS}
    assert id(vars(lq)["_TABLES"]) in declared
    assert id(vars(sdf_occlusion)["_FROZEN"]) in declared
    assert id(vars(method_fit)["_RESIDUALS"]) in declared and id(vars(method_fit)["_KEEP_ALIVE"]) in declared


def test_a_table_rebuilt_after_forgetting_gives_the_same_irradiance():
    rows, cols = 8, 16
    theta = (np.arange(rows) + 0.5) * np.pi / rows
    phi = 2.0 * np.pi * (np.arange(cols) + 0.5) / cols
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    d = np.stack([np.sin(th) * np.sin(ph), np.sin(th) * np.cos(ph), np.cos(th)], -1).reshape(-1, 3)
    wl = (np.sin(th) * (np.pi / rows) * (2.0 * np.pi / cols)).reshape(-1, 1) * (1.0 + d[:, :1] ** 2)
    normals = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, -1.0, 0.0]])
    direct = np.maximum(normals @ d.T, 0.0) @ wl  # Σ_k wl_k max(n·d_k, 0), written here

    def build():
        return lq.latlong_table(d, wl, rows, cols)

    first = lq.table_irradiance(normals, lq.cached_table("planted", build))
    runner.forget_memos()
    assert "planted" not in vars(lq)["_TABLES"]
    again = lq.table_irradiance(normals, lq.cached_table("planted", build))
    np.testing.assert_array_equal(first, again)
    np.testing.assert_allclose(first, direct, rtol=1e-12, atol=1e-15)
    runner.forget_memos()


def test_release_memory_frees_cycles_then_freezes_the_survivors():
    """`runner.release_memory` collects the cycles an experiment left (a big array held only by a cycle is
    freed), then freezes what is still alive (`gc.freeze`, issue 33: later collections skip the modules'
    heap); an object created after it, in a cycle, is still collected."""
    import gc
    import weakref

    import numpy as np

    class Node:
        pass

    def cycle() -> weakref.ref:
        a, b = Node(), Node()
        a.other, b.other, a.payload = b, a, np.ones(1 << 20)
        return weakref.ref(a)

    before = cycle()
    runner.release_memory()
    assert before() is None and gc.get_freeze_count() > 0
    after = cycle()
    gc.collect()
    assert after() is None
