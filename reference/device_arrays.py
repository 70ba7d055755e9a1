"""Host arrays on the device: (N, 3) points and normals as Mitsuba vectors, converted there.

A per-point pass (`rtfit.reference.estimators.point_chunks`, `irradiance_pass`) takes its probes as Dr.Jit
arrays; `device_components` and `device_vectors` copy an (N, 3) NumPy array's bytes to the device once and
gather and convert its columns there, and `DeviceProbes` (`device_probes`, `as_device_probes`) keeps one
reference's probe points and normals there for all its passes (issue 21 §3).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

_ALIGN = 64
"""Bytes: every host buffer Dr.Jit maps here starts on a multiple of this (`mapped_floats`)."""


def mapped_floats(Float: type, values) -> object:
    """``values`` flat as a ``Float`` array (Mitsuba's ``mi.Float``, ``mi.Float64``, …) over a fresh host
    buffer whose first element is 64-byte aligned, which Dr.Jit's LLVM backend maps without copying (CUDA
    copies the values to the device as they are: no aligned host copy first); float64 values round to
    nearest into float32, as NumPy's ``astype``.

    A mapped NumPy array's alignment is part of the kernel that reads it: the LLVM backend loads an input
    whose address is not a multiple of the vector width with ``align 1``, and a gather from it differs too
    (Dr.Jit 1.5, checked on a 4 KiB buffer shifted by 4 and 16 bytes), so a kernel of k host inputs has up to
    2^k variants as NumPy's allocator (16-byte granules) happens to place them, each compiled anew (issue 33,
    session 31: the kernels reading (N, 3) columns copied by ``np.ascontiguousarray``). The same rule as
    `rtfit.realtime.arrays.to_drjit`, which this package may not import (tests/test_layering.py)."""
    dtype = np.float64 if dr.type_v(Float) == dr.VarType.Float64 else np.float32
    a = np.asarray(values).reshape(-1)
    if dr.backend_v(Float) != dr.JitBackend.LLVM:  # CUDA copies to device memory: no second host copy
        return Float(np.ascontiguousarray(a, dtype))
    buf = np.empty(a.size + _ALIGN // np.dtype(dtype).itemsize, dtype)
    start = (-buf.ctypes.data) % _ALIGN // buf.itemsize
    out = buf[start : start + a.size]
    out[...] = a
    return Float(out)


def device_components(mi, arr) -> list:
    """The three columns of an (N, 3) float32 or float64 array (other dtypes: converted to float64) as Dr.Jit
    arrays of that precision, made **on the device**: the array's row-major bytes go there in one copy and
    the columns are gathered there (lazily: they are evaluated with whatever uses them). Host-side NumPy work
    per point (a transposed copy, a dtype conversion) cost more than the AO probe pass's kernels on the H200
    machine's CPU (≈ 30 ms for 673k points against a 5 ms kernel; issue 21 §3, docs/benchmarks.md), and Dr.Jit
    converts a transposed (strided) NumPy view element by element (6–29 ms for 673k points on 2 cores)."""
    a = np.asarray(arr)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"expected an (N, 3) array (got shape {a.shape})")
    if a.dtype not in (np.float32, np.float64):
        a = a.astype(np.float64)
    flat_type = mi.Float64 if a.dtype == np.float64 else mi.Float32
    flat = mapped_floats(flat_type, a)
    row = dr.arange(mi.UInt32, len(a)) * 3
    return [dr.gather(flat_type, flat, row + k) for k in range(3)]


def device_vectors(mi, vector_type, arr):
    """An (N, 3) array as a Mitsuba float32 3-vector array ``vector_type`` (e.g. ``mi.Point3f``), converted on
    the device (`device_components`; float64 rounds to nearest, as NumPy's ``astype(float32)``), evaluated."""
    v = vector_type(*[mi.Float32(c) for c in device_components(mi, arr)])
    dr.eval(v)
    return v


@dataclass(frozen=True)
class DeviceProbes:
    """Probe points and normals resident on the device (``mi.Point3f`` / ``mi.Vector3f``, float32), made once
    by `device_probes` and used by every pass of a reference: a pass from host arrays copies them to the
    device each time (25 MB for 1M probes: ≈ 4.7 ms on the H200 machine, a quarter of a 1M × 64 spp pass;
    issue 21 §3, docs/benchmarks.md). ``unit``: the normals were normalised (`device_probes`)."""

    points: object
    normals: object
    unit: bool

    @property
    def count(self) -> int:
        """The number of probes."""
        return dr.width(self.points)


def device_probes(mi, points, normals, normalise: bool) -> DeviceProbes:
    """``points`` and ``normals`` ((N, 3) arrays) on the device. ``normalise``: the normals divided by their
    length in float64 on the device, then rounded to float32 (zero, NaN, infinite normals and lengths whose
    square overflows are refused: ValueError); otherwise rounded to float32 as they are."""
    points, normals = np.asarray(points), np.asarray(normals)
    if points.ndim != 2 or points.shape[1] != 3 or normals.shape != points.shape:
        raise ValueError(f"points and normals must both be (N, 3) (got {points.shape} and {normals.shape})")
    on_device = device_vectors(mi, mi.Point3f, points)
    if not normalise:
        return DeviceProbes(on_device, device_vectors(mi, mi.Vector3f, normals), False)
    x, y, z = (mi.Float64(c) for c in device_components(mi, normals))
    length = dr.sqrt(x * x + y * y + z * z)
    dr.eval(x, y, z, length)
    if not dr.all(dr.isfinite(length) & (length > 0)):  # NaN or ±inf components give a non-finite length
        raise ValueError("normals must be finite and non-zero (and their squared length below 1.8e308)")
    unit = mi.Vector3f(mi.Float32(x / length), mi.Float32(y / length), mi.Float32(z / length))
    dr.eval(unit)
    return DeviceProbes(on_device, unit, True)


def as_device_probes(mi, points, normals, normalise: bool) -> DeviceProbes:
    """``points`` itself where it is `DeviceProbes` (``normals`` must then be None, and with ``normalise`` its
    normals must have been normalised), else `device_probes` of the arrays."""
    if not isinstance(points, DeviceProbes):
        return device_probes(mi, points, normals, normalise)
    if normals is not None:
        raise ValueError("with DeviceProbes as the points, normals must be None (the probes carry them)")
    if normalise and not points.unit:
        raise ValueError(
            "these DeviceProbes' normals were not normalised (device_probes(..., normalise=True))"
        )
    return points
