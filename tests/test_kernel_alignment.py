"""Host arrays reach Dr.Jit's kernels through 64-byte aligned buffers, so a kernel is compiled once whatever
address NumPy gave its inputs (issue 33, session 31).

Oracle: Dr.Jit's own kernel hashes (``dr.kernel_history()``): the LLVM backend compiles a load from a mapped
host array whose address is not a multiple of the vector width differently, so one kernel read from shifted
buffers has several hashes, each compiled anew (checked here first, on raw mapped views, so that the test
can see the hazard it guards against); and NumPy's ``astype`` for the values."""

from __future__ import annotations

import drjit as dr
import numpy as np
import pytest
from drjit.llvm import Float, Float64, UInt32

from rtfit.experiments.audit_fit import tables_as_drjit
from rtfit.realtime.arrays import to_drjit
from rtfit.reference.device_arrays import device_components, mapped_floats

N = 1000
SHIFTS = (0, 8, 16, 40)  # bytes past a 64-byte boundary (NumPy's allocator gives multiples of 16)


def _shifted(values: np.ndarray, shift: int) -> np.ndarray:
    """A copy of ``values`` whose first element lies ``shift`` bytes past a 64-byte boundary."""
    item, shift = values.dtype.itemsize, shift % 64
    buf = np.empty(values.size + 128 // item, values.dtype)
    start = ((shift - buf.ctypes.data) % 64) // item
    out = buf[start : start + values.size]
    out[...] = values
    assert out.ctypes.data % 64 == shift
    return out


def _kernel_hashes(run) -> set[str]:
    """The hashes of the JIT kernels ``run()`` launches."""
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history()  # (emptied)
        run()
        return {h["hash"] for h in dr.kernel_history() if h["type"] == dr.KernelType.JIT}


def _three_input_kernel(a, b, c) -> None:
    dr.eval(a * b + c * 0.5)


@pytest.fixture(scope="module")
def columns():
    rng = np.random.default_rng(31)
    return [rng.standard_normal(N) for _ in range(3)]


def test_raw_mapped_views_compile_a_kernel_per_alignment(columns):
    """The hazard itself: the same kernel on mapped float32 views at other offsets has other hashes."""
    hashes = set()
    for shift in SHIFTS:
        views = [Float(_shifted(c.astype(np.float32), shift)) for c in columns]
        hashes |= _kernel_hashes(lambda v=views: _three_input_kernel(*v))
    assert len(hashes) > 1


@pytest.mark.parametrize(
    "convert", [to_drjit, mapped_floats], ids=["realtime.to_drjit", "reference.mapped_floats"]
)
def test_aligned_conversions_give_one_kernel_and_numpy_rounding(columns, convert):
    """`to_drjit` (realtime) and `mapped_floats` (reference): one kernel hash from inputs at any offset, and
    the float64 → float32 values NumPy's ``astype`` gives, bit for bit."""
    hashes = set()
    for shift in SHIFTS:
        arrays = [convert(Float, _shifted(c, shift)) for c in columns]  # float64 sources
        for a, c in zip(arrays, columns, strict=True):
            assert np.array_equal(np.asarray(a), c.astype(np.float32))
        hashes |= _kernel_hashes(lambda v=arrays: _three_input_kernel(*v))
    assert len(hashes) == 1


def test_device_components_gather_one_kernel_whatever_the_offset(columns):
    """`device_components`' gathers from the (N, 3) array's bytes: one kernel at any offset, the columns."""
    xyz = np.stack(columns, axis=1)
    hashes = set()
    for shift in (0, 8, 16, 24):
        src = _shifted(xyz.reshape(-1), shift).reshape(N, 3)
        parts = device_components(_MitsubaLike, src)
        hashes |= _kernel_hashes(lambda p=parts: dr.eval(*p))
        for k in range(3):
            assert np.array_equal(np.asarray(parts[k]), xyz[:, k])
    assert len(hashes) == 1


class _MitsubaLike:
    """The three types `device_components` reads from Mitsuba's module (``mi``)."""

    Float64, Float32, UInt32 = Float64, Float, UInt32


def test_tables_as_drjit_gives_one_kernel_whatever_the_offset(columns):
    """Per-pixel inputs beside a table (`audit_fit.tables_as_drjit`, the irradiance volumes' rows): one
    kernel hash from inputs at any offset (six kernels a run were compiled again before)."""
    table = np.linspace(0.0, 1.0, 27)
    hashes = set()
    for shift in SHIFTS:
        given = {"x": _shifted(columns[0], shift), "y": _shifted(columns[1], shift + 16),
                 "table": _shifted(table, shift + 8)}  # fmt: skip
        v = tables_as_drjit(given)
        assert all(isinstance(a, Float64) for a in v.values())
        idx = dr.arange(UInt32, N) % 27
        hashes |= _kernel_hashes(
            lambda v=v, i=idx: dr.eval(v["x"] * v["y"] + dr.gather(Float64, v["table"], i))
        )
    assert len(hashes) == 1
