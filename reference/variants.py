"""Mitsuba variant selection.

``llvm_ad_rgb`` (CPU, all cores) is the default; ``cuda_ad_rgb`` is used when a CUDA device is
present and asked for with ``"auto"``; ``scalar_rgb`` is selectable for debugging and cross-checks
(it is slow: rtfit calls the integrator one sample at a time from Python there).
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import sys
from collections.abc import Iterator

import drjit as dr

from .mitsuba_log import route_mitsuba_log

KNOWN_VARIANTS = ("llvm_ad_rgb", "cuda_ad_rgb", "scalar_rgb")


def cuda_available() -> bool:
    try:
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except RuntimeError:  # Dr.Jit raises when the CUDA driver is absent
        return False


def _llvm_missing() -> str:
    """Why the LLVM backend is unavailable, in one line (issue 32: a wrong ``$DRJIT_LIBLLVM_PATH`` gave 57
    lines of traceback after ``out/`` and a cache entry were made)."""
    path = os.environ.get("DRJIT_LIBLLVM_PATH", "")
    where = (
        f"$DRJIT_LIBLLVM_PATH={path} is not a file"
        if path and not os.path.isfile(path)
        else "libLLVM did not load"
    )
    return (
        f"variant 'llvm_ad_rgb' needs Dr.Jit's LLVM backend, and {where} "
        "(set $DRJIT_LIBLLVM_PATH to libLLVM 19; scripts/bootstrap.sh finds it)"
    )


def resolve_variant(name: str = "auto") -> str:
    """Map ``"auto"`` to the best available variant; validate explicit names (one-line error), and that
    the variant's backend loads (an LLVM variant without libLLVM is refused here, before anything runs)."""
    if name == "auto":
        name = "cuda_ad_rgb" if cuda_available() else "llvm_ad_rgb"
    if name not in KNOWN_VARIANTS:
        raise ValueError(f"unknown variant {name!r} (expected one of: auto, {', '.join(KNOWN_VARIANTS)})")
    if name == "cuda_ad_rgb" and not cuda_available():
        raise ValueError("variant 'cuda_ad_rgb' needs a CUDA GPU, and none was found")
    if name.startswith("llvm") and not dr.has_backend(dr.JitBackend.LLVM):
        raise ValueError(_llvm_missing())
    return name


INSPECTION_VARIANTS = ("scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb")
"""The variants rtfit reads scenes in (parsing, listing, bounding boxes), in order of preference."""


def inspection_variant() -> str:
    """The variant to read a scene in: the active one where it is one of `INSPECTION_VARIANTS` (no switch),
    else ``scalar_rgb`` (no JIT: nothing is compiled to look at a scene), else the first installed JIT
    variant whose backend works here. A Mitsuba built or packed without the scalar variants (the GPU
    machine's pack carries only the JIT variants) still reads scenes.

    Why the active one first (issue 33): switching Mitsuba back into a JIT variant re-imports its Python
    integrators (each class through Dr.Jit's AST rewrite), 0.12 s a switch here; reading each scene in
    ``scalar_rgb`` from ``llvm_ad_rgb`` cost ~70 switches, 8 s, of the quick suite. These variants all read
    colours as RGB, so the parse and what rtfit reads from it are the same (tests/test_variant_scope.py)."""
    import mitsuba

    active = mitsuba.variant()
    if active in INSPECTION_VARIANTS:
        return active
    have = set(mitsuba.variants())  # the variants Mitsuba was built with; a pack may have dropped some:
    for v in INSPECTION_VARIANTS:  # so look for the variant's module itself
        if v not in have or importlib.util.find_spec(f"mitsuba.{v}") is None:
            continue
        if v.startswith("llvm") and not dr.has_backend(dr.JitBackend.LLVM):
            continue
        if v.startswith("cuda") and not cuda_available():
            continue
        return v
    raise RuntimeError(f"no Mitsuba variant to read scenes in (installed: {', '.join(sorted(have))})")


def use_variant(name: str = "auto"):
    """Activate a Mitsuba variant and return the ``mitsuba`` module."""
    import mitsuba as mi

    variant = resolve_variant(name)
    if mi.variant() != variant:
        mi.set_variant(variant)
    route_mitsuba_log(mi)  # its warnings on stderr through logging, not on stdout in colour
    return mi


@contextlib.contextmanager
def scoped_variant(name: str = "auto") -> Iterator:
    """`use_variant` for the duration of a ``with`` block: yields the ``mitsuba`` module and puts the
    caller's variant back afterwards (Mitsuba's variant is process-wide state; a notebook's own variant
    must survive an rtfit call)."""
    import mitsuba

    caller = mitsuba.variant()
    mi = use_variant(name)
    try:
        yield mi
    finally:
        if caller and caller != mi.variant():
            mi.set_variant(caller)


@contextlib.contextmanager
def callers_variant() -> Iterator[None]:
    """Put the caller's Mitsuba variant back at the end of the block, whatever the block activated.

    For rtfit's entry points that render (`rtfit.reference.render_gbuffer`, `ReferenceCache.get`,
    `rtfit.experiments.runner.run_experiments`): a notebook working in ``scalar_rgb`` keeps it. Where
    Mitsuba was not imported yet, or no variant was set, there is nothing to put back."""
    mi = sys.modules.get("mitsuba")
    caller = mi.variant() if mi is not None else None
    try:
        yield
    finally:
        if caller:
            import mitsuba

            if mitsuba.variant() != caller:
                mitsuba.set_variant(caller)


def is_scalar(variant: str) -> bool:
    return variant.startswith("scalar")


def backend_of(variant: str) -> str:
    """The Dr.Jit backend name ("llvm", "cuda" or "scalar") a variant computes on."""
    return variant.split("_", 1)[0]
