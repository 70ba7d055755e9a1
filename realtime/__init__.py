"""rtfit.realtime: real-time rendering approximations as kernels written once, run on Dr.Jit, NumPy and JAX.

Imports only drjit and numpy (jax when a JAX array is passed or `JAX_OPS` is asked for). Public functions
accept Python floats, NumPy arrays (evaluated on the default Dr.Jit backend, see `set_default_backend`),
Dr.Jit arrays (same type out) or JAX arrays (JAX out, differentiable); see `rtfit.realtime.arrays`.

Every public name of every module of this package is importable from the package's root
(``from rtfit.realtime import sphere_light_irradiance, height_fog_optical_depth``), whatever module it
lives in, so that moving a function between modules never breaks a user. The modules are found, not
listed: `MODULES` is every module file of this folder (`pkgutil`), and a name of the root is looked up on
first use (PEP 562 module ``__getattr__``) in the ``__all__`` of the module that exports it, which is then
imported — alone: ``import rtfit.realtime`` imports no module (nor Dr.Jit), ``from rtfit.realtime import
NUMPY_OPS`` imports `arrays` only. A family's module added to the folder is part of the root with no edit
here (docs/architecture.md, "Adding a family"); tests/test_layering.py checks that no two modules export
the same name.

Two root names are a function that shadows a module of the same name (`SHADOWING`): ``volumetric_lightning``
(the issue's public name; its module's names are imported with ``from rtfit.realtime.volumetric_lightning
import METHODS``, and ``import rtfit.realtime.volumetric_lightning as m`` binds the function) and
``aerial_perspective`` (`nishita_sky.aerial_perspective`; the aerial-perspective family's module is
``rtfit.realtime.aerial_perspective``). The root keeps the function even after the module is imported.

The shared modules (each family has its own module, whose docstring says what it holds, its formula and its
doc page, docs/<family>.md):
    arrays      the ops namespaces (Dr.Jit, NumPy, JAX), dispatch, guards and small stable helpers.
    methods     methods as data: `Method`, `Param`, `Input`, `method_table`.
    nonnegative_lsq  non-negative least squares (Lawson–Hanson) for the probe bakes' NNLS fits.
    phase       phase functions (Rayleigh, Henyey–Greenstein, Cornette–Shanks), one text for all media.
    quantities  what an approximation approximates and the inputs its ``g`` carries; the `approximation`
                decorator for a user's own formula (docs/audit.md, "Your own approximation"); the table's
                rooms: quantity_types (the `Quantity` record, shared inputs), quantities_lights,
                quantities_sky, quantities_media, quantities_probes, quantities_materials, and each
                family module's own ``QUANTITIES``.
    shader      GLSL/HLSL text traced from the kernels (`SHADER_OPS`, `shader_function`).
"""

import ast as _ast
import pkgutil as _pkgutil
import re as _re
import sys as _sys
import types as _types
from importlib import import_module as _import_module
from pathlib import Path as _Path
from typing import Any as _Any

MODULES: tuple[str, ...] = tuple(
    sorted(m.name for m in _pkgutil.iter_modules(__path__) if not m.name.startswith("_") and not m.ispkg)
)
"""The modules whose public names this package re-exports: every module file of this folder, by name."""

SHADOWING: dict[str, str] = {
    "volumetric_lightning": "volumetric_lightning",
    "aerial_perspective": "nishita_sky",
}
"""Root name → the module whose exported function it is, where a module of the same name exists (module
docstring); tests/test_layering.py checks that these are exactly the names both a module and an export."""

_ALL = _re.compile(r"^__all__\b[^=\n]*=", _re.M)
_exports: dict[str, str] | None = None


def _declared_all(name: str) -> list[str]:
    """The ``__all__`` of module ``name`` read from its source text (a literal list or tuple, as every module
    here writes it), without importing it; imported where it is not a literal."""
    try:
        text = _Path(__path__[0], f"{name}.py").read_text(encoding="utf-8")
    except OSError:  # no source file (an install of bytecode only): its module tells
        text = ""
    found = _ALL.search(text)
    if found is None:
        return list(getattr(_import_module(f"{__name__}.{name}"), "__all__", ())) if not text else []
    lines = text[found.end() :].splitlines()
    for n in range(1, min(len(lines), 400) + 1):  # the shortest run of lines that is the whole literal
        try:
            value = _ast.literal_eval("\n".join(lines[:n]).strip())
        except (SyntaxError, ValueError):
            continue
        return [str(v) for v in value]
    return list(getattr(_import_module(f"{__name__}.{name}"), "__all__", ()))


def exports() -> dict[str, str]:
    """Every exported name → the module exporting it (the first in `MODULES` order where two do)."""
    global _exports
    if _exports is None:
        found: dict[str, str] = {}
        for name in MODULES:
            for attr in _declared_all(name):
                found.setdefault(attr, name)
        _exports = found
    return _exports


class _Root(_types.ModuleType):
    """The package's module type: each name of `SHADOWING` is a property reading the function, so that it
    stays the function after the import system binds the shadowed submodule on the package
    (``setattr(package, name, module)``, which the property's setter ignores)."""


def _shadowing(name: str) -> property:
    def read(_package: _types.ModuleType) -> _Any:
        return getattr(_import_module(f"{__name__}.{SHADOWING[name]}"), name)

    def bind(_package: _types.ModuleType, value: _Any) -> None:
        if not isinstance(value, _types.ModuleType):
            raise AttributeError(f"{__name__}.{name} is {SHADOWING[name]}.{name} (read-only)")

    return property(read, bind, doc=f"{SHADOWING[name]}.{name}")


for _name in SHADOWING:
    setattr(_Root, _name, _shadowing(_name))
_sys.modules[__name__].__class__ = _Root


def __getattr__(name: str) -> _Any:
    # JAX_OPS is built on first use (it imports jax): see rtfit.realtime.arrays.
    if name == "JAX_OPS":
        return _import_module(f"{__name__}.arrays").jax_ops()
    if name == "__all__":  # ``from rtfit.realtime import *``: every module and every exported name
        return sorted({*MODULES, *exports(), "MODULES", "SHADOWING", "exports"})
    if name in MODULES:
        return _import_module(f"{__name__}.{name}")
    owner = exports().get(name)
    if owner is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(_import_module(f"{__name__}.{owner}"), name)
    globals()[name] = value  # later look-ups skip this hook
    return value


def __dir__() -> list[str]:
    return sorted({*(k for k in globals() if not k.startswith("_")), *MODULES, *exports()})
