"""Architecture rules, checked on the source text of the five packages.

1. Dependencies flow one way: scenes → reference, realtime → fitting → experiments (imports anywhere in a
   module, including inside functions); scenes, realtime and fitting never import mitsuba.
2. No import cycle inside a package (every import counts, also one inside a function: a cycle that only
   works because one side imports late is still a cycle).
3. No private name crosses a module boundary: neither ``from .x import _name`` nor ``x._name`` on an
   imported rtfit module.
4. Imports sit at module top, except the heavy optional ones (`LAZY_OK`): an import inside a function of
   anything else is a finding.
5. Every public function of `rtfit.realtime` is importable from the package root, and no two modules
   export the same name.
6. No family module imports another family module (issue 30 §3): the family modules are the experiment
   modules of the registry (`families.FAMILIES`) and the ``audit_<family>.py`` modules that declare an
   `AuditFamily`
   (an audit module importing its experiment module counts too: what both need goes in a shared module).
   Today's violations are an explicit allow-list (`FAMILY_IMPORTS_ALLOWED`) that may only shrink.
7. A family module has at most `FAMILY_MAX_LINES` lines; today's larger ones are listed with their line
   counts as ceilings (`FAMILY_LINES_CEILING`): a ratchet, none may grow.
8. One backend switch (issue 30 §3): ``set_default_backend(…)`` is called in `BACKEND_SWITCH` alone (the
   engine's entry points call `runner.use_variant_backend`), and no module picks an array type by hand
   (``dr.cuda.Float if …``; `rtfit.realtime.arrays.backend_float` is the one place).

Rules 2–4 and 6–8 are plain functions of a directory, so the tests below also run them on planted
packages to show that each rule catches what it is meant to.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("scenes", "reference", "realtime", "fitting", "experiments")
ALLOWED = {
    "scenes": {"scenes"},
    "reference": {"scenes", "reference"},
    "realtime": {"realtime"},
    "fitting": {"realtime", "fitting"},
    "experiments": {"scenes", "reference", "realtime", "fitting", "experiments"},
}
NO_MITSUBA = {"scenes", "realtime", "fitting"}
LAZY_OK = {
    # Heavy or optional: importing them at module top would make every `import rtfit.…` pay for them (JAX
    # ≈ 1 s, matplotlib ≈ 0.5 s, Ray ≈ 2 s), select a Mitsuba variant process-wide, or fail where the
    # optional extra is absent.
    "mitsuba",
    # drjit starts loading CUDA on a background thread when imported: a GPU worker (process pool, Ray
    # actor) must import it only after it has chosen its device (CUDA_VISIBLE_DEVICES).
    "drjit",
    "jax",
    "jaxlib",
    "equinox",
    "optimistix",
    "lineax",
    "matplotlib",
    "ray",
    "scipy",
    "skimage",
    "flip_evaluator",
    "OpenEXR",
    "Imath",
    "mpmath",
    "tqdm",
    "pandas",  # optional, not a dependency: AuditResult.to_dataframe only (experiments/audit_api.py)
}
FAMILY_IMPORTS_ALLOWED = {
    # Rule 6's violations today; remove an entry when its import goes (the test fails on a stale entry).
    # The audit roles share the AO reference, the light geometry and the environment bases by importing
    # each other's modules (these belong in a shared audit module):
    "audit_ambient_aperture -> audit_ambient_occlusion",  # ao_reference, scene_distance_field
    "audit_sky_occlusion -> audit_ambient_occlusion",  # DistanceFieldRows, distance_field_rows
    # An audit declaration reads its experiment module's parameter sources and fits:
}
FAMILY_MAX_LINES = 600
FAMILY_LINES_CEILING = {
    # Rule 7's ratchet: today's family modules over FAMILY_MAX_LINES, each at most its line count of today.
    # Lower a ceiling when its module shrinks; drop it at FAMILY_MAX_LINES or below.
}


def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"), filename=str(path))


def _absolute(module: str, node: ast.ImportFrom, package: str) -> str:
    """The absolute dotted name an ImportFrom refers to (relative imports resolved inside ``package``)."""
    if node.level == 0:
        return node.module or ""
    base = f"rtfit.{package}"
    return f"{base}.{node.module}" if node.module else base


def _imports(path: Path, package: str):
    """Yield (absolute module name, imported names or None, node, inside_function) for every import."""
    tree = _tree(path)
    funcs = (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)

    def walk(node, in_func):
        for child in ast.iter_child_nodes(node):
            inside = in_func or isinstance(child, funcs)
            if isinstance(child, ast.Import):
                for a in child.names:
                    yield a.name, None, child, in_func
            elif isinstance(child, ast.ImportFrom):
                yield _absolute(path.stem, child, package), [a.name for a in child.names], child, in_func
            yield from walk(child, inside)

    yield from walk(tree, False)


def _local_modules(pkg_dir: Path) -> set[str]:
    return {p.stem for p in pkg_dir.glob("*.py")}


def find_layer_violations(root: Path, package: str) -> list[str]:
    bad = []
    for path in sorted((root / package).glob("*.py")):
        for name, names, _, _ in _imports(path, package):
            targets = [name] + ([f"{name}.{n}" for n in names] if names and name.count(".") == 1 else [])
            for t in targets[:1]:
                if t.startswith("rtfit."):
                    sub = t.split(".")[1]
                    if sub not in ALLOWED[package]:
                        bad.append(f"{path.name}: {t}")
            if package in NO_MITSUBA and name.split(".")[0] == "mitsuba":
                bad.append(f"{path.name}: {name}")
    return bad


def _module_edges(root: Path, package: str) -> dict[str, set[str]]:
    """Module → modules of the same package it imports (any import, anywhere in the module)."""
    pkg = root / package
    local = _local_modules(pkg)
    prefix = f"rtfit.{package}"
    edges: dict[str, set[str]] = {m: set() for m in local}
    for path in sorted(pkg.glob("*.py")):
        for name, names, _, _ in _imports(path, package):
            if name == prefix and names:  # from . import a, b
                edges[path.stem] |= {n for n in names if n in local}
            elif name.startswith(prefix + "."):
                mod = name[len(prefix) + 1 :].split(".")[0]
                if mod in local:
                    edges[path.stem].add(mod)
    for m in edges:
        edges[m].discard(m)
        edges[m].discard("__init__")  # the package's own __init__ re-exports; importing it is no cycle
    edges.pop("__init__", None)
    return edges


def find_cycles(root: Path, package: str) -> list[list[str]]:
    """Every elementary cycle's strongly connected component (Tarjan), as sorted module lists."""
    edges = _module_edges(root, package)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def strong(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            strong(v)
    return out


def _module_aliases(tree: ast.Module, package: str) -> set[str]:
    """Names bound to rtfit modules by imports (``from . import figures``, ``from rtfit.realtime import sky``,
    ``import rtfit.x.y as z``)."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            mod = _absolute("", node, package)
            if mod.startswith("rtfit"):
                for a in node.names:
                    target = f"{mod}.{a.name}"
                    if _is_rtfit_module(target):
                        names.add(a.asname or a.name)
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("rtfit.") and a.asname:
                    names.add(a.asname)
    return names


def _is_rtfit_module(dotted: str) -> bool:
    parts = dotted.split(".")
    if len(parts) == 2:  # rtfit.<package>
        return parts[1] in PACKAGES
    if len(parts) == 3 and parts[1] in PACKAGES:
        return (ROOT / parts[1] / f"{parts[2]}.py").is_file()
    return False


def find_private_imports(root: Path, package: str) -> list[str]:
    """``from X import _name`` of another module, and ``module._name`` on an imported rtfit module."""
    bad = []
    for path in sorted((root / package).glob("*.py")):
        tree = _tree(path)
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                mod = _absolute(path.stem, node, package)
                if not mod.startswith("rtfit") and node.level == 0:
                    continue
                for a in node.names:
                    if a.name.startswith("_") and not a.name.startswith("__"):
                        bad.append(f"{path.name}:{node.lineno}: from {mod} import {a.name}")
        aliases = _module_aliases(tree, package)
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Attribute)
                and isinstance(node.value, ast.Name)
                and node.value.id in aliases
                and node.attr.startswith("_")
                and not node.attr.startswith("__")
            ):
                bad.append(f"{path.name}:{node.lineno}: {node.value.id}.{node.attr}")
    return bad


def find_lazy_imports(root: Path, package: str) -> list[str]:
    """Imports inside functions of anything but the heavy optional modules (`LAZY_OK`)."""
    bad = []
    for path in sorted((root / package).glob("*.py")):
        for name, _, node, in_func in _imports(path, package):
            if in_func and name.split(".")[0] not in LAZY_OK:
                bad.append(f"{path.name}:{node.lineno}: {name}")
    return bad


def family_modules(root: Path) -> set[str]:
    """Stems of the family modules of ``root``/experiments: the experiment modules the registry names (read
    from families.py's text, ``"rtfit.experiments.<name>"``) and the ``audit_*.py`` modules declaring an
    `AuditFamily` at their top level (``NAME = AuditFamily(...)``)."""
    pkg = root / "experiments"
    registry = (pkg / "families.py").read_text(encoding="utf-8") if (pkg / "families.py").is_file() else ""
    names = set(re.findall(r'"rtfit\.experiments\.([a-z0-9_]+)"', registry))
    for path in pkg.glob("audit_*.py"):
        for node in _tree(path).body:
            call = node.value if isinstance(node, (ast.Assign, ast.AnnAssign)) else None
            if isinstance(call, ast.Call) and getattr(call.func, "id", None) == "AuditFamily":
                names.add(path.stem)
                break
    return {n for n in names if (pkg / f"{n}.py").is_file()}


def find_family_imports(root: Path) -> list[str]:
    """``module -> other``: a family module importing (anywhere in it) another family module."""
    families = family_modules(root)
    edges = _module_edges(root, "experiments")
    return [f"{m} -> {t}" for m in sorted(families) for t in sorted(edges.get(m, ())) if t in families]


def find_large_families(root: Path, ceilings: dict[str, int]) -> list[str]:
    """Family modules longer than `FAMILY_MAX_LINES` lines, or than their ceiling in ``ceilings``."""
    bad = []
    for m in sorted(family_modules(root)):
        n = len((root / "experiments" / f"{m}.py").read_text(encoding="utf-8").splitlines())
        limit = max(FAMILY_MAX_LINES, ceilings.get(m, 0))
        if n > limit:
            bad.append(f"{m}.py: {n} lines > {limit}")
    return bad


BACKEND_SWITCH = {"experiments/runner.py", "realtime/arrays.py"}
"""Where ``set_default_backend`` may be called (the engine's `use_variant_backend`; its definition)."""
_HAND_SWITCH = re.compile(r"dr\.(cuda|llvm)\.\w+ if ")


def find_backend_switches(root: Path) -> list[str]:
    """Calls of ``set_default_backend`` outside `BACKEND_SWITCH`, and array types picked by hand."""
    bad = []
    for package in PACKAGES:
        for path in sorted((root / package).glob("*.py")):
            rel = f"{package}/{path.name}"
            text = path.read_text(encoding="utf-8")
            for node in ast.walk(_tree(path)):
                if isinstance(node, ast.Call) and getattr(
                    node.func, "id", getattr(node.func, "attr", None)
                ) == ("set_default_backend"):
                    if rel not in BACKEND_SWITCH:
                        bad.append(f"{rel}:{node.lineno}: set_default_backend")
            for i, line in enumerate(text.splitlines(), 1):
                if _HAND_SWITCH.search(line):
                    bad.append(f"{rel}:{i}: {line.strip()}")
    return bad


# ------------------------------------------------------------------------------------------- the tree
def test_one_backend_switch():
    bad = find_backend_switches(ROOT)
    assert not bad, f"the Dr.Jit backend is set outside the engine's entry points: {bad}"


@pytest.mark.parametrize("package", PACKAGES)
def test_imports_follow_the_layering(package):
    bad = find_layer_violations(ROOT, package)
    assert not bad, f"{package} imports outside its layer: {bad}"


@pytest.mark.parametrize("package", PACKAGES)
def test_no_import_cycle_inside_a_package(package):
    cycles = find_cycles(ROOT, package)
    assert not cycles, f"rtfit.{package} has import cycles: {cycles}"


@pytest.mark.parametrize("package", PACKAGES)
def test_no_private_name_crosses_a_module(package):
    bad = find_private_imports(ROOT, package)
    assert not bad, f"rtfit.{package} uses private names of other modules: {bad}"


@pytest.mark.parametrize("package", PACKAGES)
def test_imports_at_module_top(package):
    bad = find_lazy_imports(ROOT, package)
    assert not bad, f"rtfit.{package}: imports inside functions (only {sorted(LAZY_OK)} may be): {bad}"


def test_every_public_realtime_function_is_importable_from_the_root():
    realtime = importlib.import_module("rtfit.realtime")
    owner: dict[str, str] = {}
    missing, dup = [], []
    for name in realtime.MODULES:
        mod = importlib.import_module(f"rtfit.realtime.{name}")
        exported = set(getattr(mod, "__all__", ()))
        for attr, obj in vars(mod).items():
            if attr.startswith("_") or not (inspect.isfunction(obj) or inspect.isclass(obj)):
                continue
            if getattr(obj, "__module__", None) != mod.__name__:
                continue
            if attr not in exported:
                missing.append(f"{name}.{attr} (not in __all__)")
            elif getattr(realtime, attr, None) is not obj:
                missing.append(f"{name}.{attr} (not the root's)")
        for attr in exported:
            if attr in owner and owner[attr] != name:
                dup.append(f"{attr}: {owner[attr]} and {name}")
            owner.setdefault(attr, name)
    modules = {p.stem for p in (ROOT / "realtime").glob("*.py")} - {"__init__"}
    assert modules == set(realtime.MODULES), f"realtime.MODULES is not the module list: {sorted(modules)}"
    assert not missing, f"public realtime names not importable from rtfit.realtime: {missing}"
    assert not dup, f"two realtime modules export the same name: {dup}"
    # The root's index (read from the modules' source) is each module's own __all__.
    assert realtime.exports() == owner
    # A root name that is also a module's name is the exported function (the package's SHADOWING list).
    shadowing = {attr: name for attr, name in owner.items() if attr in realtime.MODULES}
    assert shadowing == realtime.SHADOWING
    for attr, name in shadowing.items():
        importlib.import_module(f"rtfit.realtime.{attr}")  # the import system binds the module: ignored
        assert getattr(realtime, attr) is getattr(importlib.import_module(f"rtfit.realtime.{name}"), attr)


def test_the_realtime_root_imports_lazily():
    """``import rtfit.realtime`` imports none of its modules (nor Dr.Jit); a root name imports only the
    module that exports it, a submodule name only that module."""
    code = (
        "import sys, rtfit.realtime as r\n"
        "def loaded(): return sorted(m for m in sys.modules if m.startswith('rtfit.realtime.'))\n"
        "print(loaded(), 'drjit' in sys.modules)\n"
        "from rtfit.realtime import NUMPY_OPS\n"
        "print(loaded())\n"
        "from rtfit.realtime import fresnel\n"
        "print(loaded(), fresnel.__name__)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.splitlines() == [
        "[] False",
        "['rtfit.realtime.arrays']",
        "['rtfit.realtime.arrays', 'rtfit.realtime.fresnel', 'rtfit.realtime.methods']"
        " rtfit.realtime.fresnel",
    ], out


def test_no_family_module_imports_another():
    found = set(find_family_imports(ROOT))
    new, stale = sorted(found - FAMILY_IMPORTS_ALLOWED), sorted(FAMILY_IMPORTS_ALLOWED - found)
    assert not new, f"family modules import other family modules (use a shared module): {new}"
    assert not stale, f"FAMILY_IMPORTS_ALLOWED lists imports that are gone; remove them: {stale}"


def test_family_modules_do_not_grow():
    bad = find_large_families(ROOT, FAMILY_LINES_CEILING)
    assert not bad, f"family modules over their line limit (split a study into a leaf module): {bad}"
    stale = sorted(set(FAMILY_LINES_CEILING) - family_modules(ROOT))
    assert not stale, f"FAMILY_LINES_CEILING names modules that are not family modules: {stale}"


# ----------------------------------------------------------------------------------- planted defects
def _plant(tmp_path: Path, files: dict[str, str]) -> Path:
    pkg = tmp_path / "experiments"
    pkg.mkdir()
    for name, text in files.items():
        (pkg / name).write_text(text, encoding="utf-8")
    return tmp_path


def test_a_planted_cycle_is_found(tmp_path):
    root = _plant(
        tmp_path,
        {
            "__init__.py": "",
            "a.py": "from . import b\n",
            "b.py": "def f():\n    from .c import g\n    return g\n",  # late import: still a cycle
            "c.py": "from rtfit.experiments.a import x\n",
            "d.py": "from . import a\n",  # imports into the cycle, not part of it
        },
    )
    assert find_cycles(root, "experiments") == [["a", "b", "c"]]


def test_a_planted_private_import_is_found(tmp_path):
    root = _plant(
        tmp_path,
        {
            "__init__.py": "",
            "a.py": "def _helper():\n    return 1\n",
            "b.py": "from .a import _helper\n",
            "c.py": "from rtfit.realtime import diffuse\nx = diffuse._wrap_kernel\n",
            "d.py": "from .a import __all__\nimport os\nx = os._exit\n",  # dunder and non-rtfit: fine
        },
    )
    found = find_private_imports(root, "experiments")
    assert found == ["b.py:1: from rtfit.experiments.a import _helper", "c.py:2: diffuse._wrap_kernel"]


def test_a_planted_lazy_import_is_found(tmp_path):
    root = _plant(
        tmp_path,
        {"__init__.py": "", "a.py": "def f():\n    import jax\n    import json\n    from . import b\n"},
    )
    assert find_lazy_imports(root, "experiments") == ["a.py:3: json", "a.py:4: rtfit.experiments"]


def _planted_families(tmp_path: Path, files: dict[str, str]) -> Path:
    registry = 'EXPERIMENTS = [Spec("a", "rtfit.experiments.a"), Spec("b", "rtfit.experiments.b")]\n'
    return _plant(tmp_path, {"__init__.py": "", "families.py": registry, **files})


def test_a_planted_family_import_is_found(tmp_path):
    declared = "from .audit_family import AuditFamily\nFAMILY = AuditFamily(name='a')\n"
    root = _planted_families(
        tmp_path,
        {
            "a.py": "from .b import x\nfrom .shared import y\nfrom .audit_helper import z\n",
            "b.py": "from . import shared\n",
            "shared.py": "",  # not a family: anyone may import it
            "c.py": "from . import a, b\n",  # not a family (not registered): may import families
            "audit_a.py": declared + "def f():\n    from . import b\n    import rtfit.experiments.a\n",
            "audit_helper.py": "from . import a\n",  # declares no family: a shared audit module
            "audit_family.py": "class AuditFamily:\n    pass\n",
        },
    )
    assert family_modules(root) == {"a", "b", "audit_a"}
    assert find_family_imports(root) == ["a -> b", "audit_a -> a", "audit_a -> b"]


def test_a_planted_large_family_is_found(tmp_path):
    lines = "x = 1\n"
    root = _planted_families(
        tmp_path,
        {"a.py": lines * (FAMILY_MAX_LINES + 1), "b.py": lines * 700, "c.py": lines * 900},  # c: no family
    )
    n = FAMILY_MAX_LINES
    assert find_large_families(root, {"b": 700}) == [f"a.py: {n + 1} lines > {n}"]
    assert find_large_families(root, {"a": 601, "b": 699}) == ["b.py: 700 lines > 699"]


def test_a_planted_backend_switch_is_found(tmp_path):
    root = _plant(
        tmp_path,
        {
            "runner.py": "def use(v):\n    set_default_backend(v)\n",
            "family.py": "import drjit as dr\nF = dr.cuda.Float if GPU else dr.llvm.Float\n"
            "def run(ctx):\n    realtime.set_default_backend('llvm')\n",
        },
    )
    assert find_backend_switches(root) == [
        "experiments/family.py:4: set_default_backend",
        "experiments/family.py:2: F = dr.cuda.Float if GPU else dr.llvm.Float",
    ]


def test_experiments_import_no_jax():
    """JAX runs rtfit's fits in fitting/ (and realtime/'s JAX ops): issue 32, experiments imported
    ``jax.numpy`` for their fits' output transforms; `rtfit.fitting.concatenated` is that transform, once."""
    found = [
        f"{path.relative_to(ROOT)}:{node.lineno}: {name}"
        for path in sorted((ROOT / "experiments").rglob("*.py"))
        for name, _, node, _ in _imports(path, "experiments")
        if name == "jax" or name.startswith("jax.")
    ]
    assert found == []
