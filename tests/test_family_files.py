"""Adding a family edits one existing file (issue 30: "one realtime module, one family declaration, its tests,
its doc page, one registry line — no other file").

Every list that names the families is derived from the family's own files: the realtime package's modules
and root names (`rtfit.realtime.MODULES`, found by `pkgutil`), the quantities (a family module's own
``QUANTITIES``, `rtfit.realtime.quantities.family_quantities`), the docs (the README says `rtfit list` names
every family and docs/<name>.md is each one's page; a family's own quantity is generated on that page), and
``rtfit list`` / ``rtfit audit --list`` (the registry, `rtfit.experiments.families`). The last test plants a
toy family in a copy of the packages — its four new files and its registry entry, nothing else — and checks
that every one of them picks it up.
"""

from __future__ import annotations

import filecmp
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

from rtfit.experiments.families import FAMILIES, METHOD_TABLES
from rtfit.realtime.quantities import QUANTITIES, QUANTITY_ORDER, family_quantities, quantities_markdown

from .test_doc_links import families_without_a_page, unlisted_pages

ROOT = Path(__file__).resolve().parent.parent


def missing_quantity_sections(
    root: Path,
    declared: dict[str, list[str]],
    shipped: dict[str, list[str]],
    sections: dict[str, str],
) -> list[str]:
    """The quantities a family module declares (``declared``: module → names) whose generated section
    (``sections``: name → `quantities_markdown` of it) is on no page docs/<family>.md of a family shipping a
    method of it (``shipped``: family → the quantities of its methods), or that no family ships."""
    bad = []
    for module, names in declared.items():
        for name in names:
            pages = [root / "docs" / f"{f}.md" for f, qs in shipped.items() if name in qs]
            texts = [p.read_text(encoding="utf-8") for p in pages if p.is_file()]
            if not any(sections[name] in t for t in texts):
                bad.append(f"{module}.QUANTITIES {name} (pages: {[p.name for p in pages]})")
    return bad


def test_quantities_are_the_rooms_then_the_family_modules():
    declared = family_quantities()
    assert list(QUANTITIES) == [*QUANTITY_ORDER, *(q.name for m in sorted(declared) for q in declared[m])]
    shipped = {f: sorted({m.quantity for m in t.values()}) for f, t in METHOD_TABLES.items()}
    names = {m: [q.name for q in qs] for m, qs in declared.items()}
    sections = {n: quantities_markdown((n,)) for ns in names.values() for n in ns}
    assert missing_quantity_sections(ROOT, names, shipped, sections) == []


def test_a_planted_module_declares_its_quantity(tmp_path, monkeypatch):
    """A module of a package that assigns ``QUANTITIES`` at its top level is imported and its quantities
    gathered; a module that does not is not imported; a wrong declaration is one ValueError."""
    pkg = tmp_path / "planted_realtime"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "glow.py").write_text(
        "from rtfit.realtime.methods import Input\n"
        "from rtfit.realtime.quantity_types import Quantity\n"
        "X = Input('x', '1', 'a planted input', (0.0, 1.0))\n"
        "QUANTITIES = (Quantity('planted_a', '1', 'a planted quantity', (X,)),\n"
        "              Quantity('planted_b', 'W/m²', 'another', (X,)))\n"
    )
    (pkg / "helper.py").write_text("raise RuntimeError('not a family module: never imported')\n")
    (pkg / "quantities_rooms.py").write_text("QUANTITIES = 1  # a room: skipped\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    found = family_quantities("planted_realtime", pkg)
    assert {m: [q.name for q in qs] for m, qs in found.items()} == {"glow": ["planted_a", "planted_b"]}
    (pkg / "wrong.py").write_text("QUANTITIES = ['planted_c']\n")
    try:
        family_quantities("planted_realtime", pkg)
    except ValueError as e:
        assert str(e) == "planted_realtime.wrong.QUANTITIES must be a tuple of Quantity"
    else:
        raise AssertionError("a wrong QUANTITIES was accepted")


def test_every_registered_family_has_its_page_and_the_readme_lists_none():
    assert families_without_a_page(ROOT, FAMILIES) == []
    assert unlisted_pages(ROOT, FAMILIES) == []


# ------------------------------------------------------------------------------------------ planted family
TOY_REALTIME = '''\
"""toy: a planted family (tests/test_family_files.py): (1 − cos θ)^p with a free exponent (docs/toy.md)."""

from __future__ import annotations

from .methods import Input, Method, Param, method_table
from .quantity_types import Quantity

__all__ = ["toy_falloff"]

COS_THETA = Input("cos_theta", "1", "cosine of the viewing angle", (0.0, 1.0))


def _toy_kernel(ops, cos_theta, p):
    return ops.power(1.0 - cos_theta, p)


def toy_falloff(cos_theta: float, p: float = 5.0) -> float:
    """(1 − cos θ)^p."""
    return (1.0 - cos_theta) ** p


METHODS = method_table(
    [
        Method(
            "toy-falloff",
            "Toy falloff",
            _toy_kernel,
            inputs=(COS_THETA,),
            params={"p": Param(5.0, 1.0, 8.0, unit="1")},
            quantity="toy_reflectance",
            formula="(1 − cos θ)^p",
        )
    ]
)

QUANTITIES = (
    Quantity(
        "toy_reflectance",
        "1",
        "a planted family's reflectance at the viewing angle",
        (COS_THETA,),
        reference="none (planted)",
    ),
)
'''

TOY_AUDIT = '''\
"""The ``toy`` family in `rtfit audit` (planted by tests/test_family_files.py): applies to every reflective
shape, audits no case."""

from __future__ import annotations

from rtfit.realtime.toy import METHODS

from .audit import Rule
from .audit_family import AuditFamily
from .shipped import ShippedScene

__all__ = ["FAMILY", "METHODS", "SCENES"]

SCENES = (ShippedScene("fresnel_spheres.xml", "the fresnel family's spheres"),)


def toy_cases(setup, app):
    """No case: the planted family is only declared."""
    return []


FAMILY = AuditFamily(
    name="toy",
    quantity="toy_reflectance",
    cases=toy_cases,
    describe="A planted family.",
    rules=(
        Rule(
            "toy",
            "toy reflectance",
            ("reflective-shape",),
            "{part}: a planted family applies to it",
            "none (planted)",
            "none (planted)",
            supplies=frozenset({"cos_theta"}),
        ),
    ),
)
'''

TOY_TEST = """\
from rtfit.realtime import toy_falloff


def test_toy_falloff_at_grazing_and_normal_incidence():
    assert toy_falloff(0.0) == 1.0 and toy_falloff(1.0) == 0.0
"""

TOY_REGISTRY_IMPORTS = "from rtfit.realtime import toy as toy_realtime\nfrom . import audit_toy\n\n"
TOY_REGISTRY_ENTRY = (
    '        _engine("toy", audit_toy, toy_realtime.METHODS, "Toy: a planted family", "Planted by a test."),'
    "\n"
)

CHECK = """
import json, sys
import rtfit.realtime as rt
from rtfit.realtime import toy_falloff
from rtfit.realtime.quantities import QUANTITIES, family_quantities, quantities_markdown
from rtfit.experiments.families import FAMILIES, METHOD_TABLES
declared = {m: [q.name for q in qs] for m, qs in family_quantities().items()}
json.dump({
    "modules": list(rt.MODULES),
    "root": toy_falloff(0.5),
    "quantities": list(QUANTITIES),
    "declared": declared,
    "sections": {n: quantities_markdown((n,)) for ns in declared.values() for n in ns},
    "families": list(FAMILIES),
    "shipped": {f: sorted({m.quantity for m in t.values()}) for f, t in METHOD_TABLES.items()},
}, sys.stdout)
"""


def _planted_tree(tmp_path: Path) -> tuple[Path, dict[str, str]]:
    """A copy of the packages a family touches (realtime, experiments, docs, README) under ``src`` and an
    import tree ``paths/rtfit`` mapping the ``rtfit.*`` names onto it (the others: the repository's own)."""
    src, pkg = tmp_path / "src", tmp_path / "paths" / "rtfit"
    ignore = shutil.ignore_patterns("__pycache__")
    for folder in ("realtime", "experiments", "docs"):
        shutil.copytree(ROOT / folder, src / folder, ignore=ignore)
    shutil.copy2(ROOT / "README.md", src / "README.md")
    (src / "tests").mkdir()
    pkg.mkdir(parents=True)
    for f in (ROOT / "rtfit").glob("*.py"):
        shutil.copy2(f, pkg / f.name)
    for name in ("realtime", "experiments"):
        (pkg / name).symlink_to(src / name, target_is_directory=True)
    for name in ("scenes", "reference", "fitting"):
        (pkg / name).symlink_to(ROOT / name, target_is_directory=True)
    env = {**os.environ, "PYTHONPATH": str(tmp_path / "paths"), "RTFIT_CACHE": str(tmp_path / "cache")}
    return src, env


def _add_registry_entry(families: Path) -> None:
    """The one edit of an existing file: the toy's entry in the registry (its imports beside it)."""
    text = families.read_text(encoding="utf-8")
    anchor = "FAMILIES: dict[str, Family] = {"
    entries = "    for f in (\n"
    assert anchor in text and entries in text.split(anchor, 1)[1], (
        "the registry's layout moved: update the test"
    )
    head, tail = text.split(anchor, 1)
    tail = tail.replace(entries, entries + TOY_REGISTRY_ENTRY, 1)
    families.write_text(head + TOY_REGISTRY_IMPORTS + anchor + tail, encoding="utf-8")


def _changed(src: Path) -> list[str]:
    """Every file of the copy that differs from the repository's or is new (paths from the root)."""
    out = []

    def walk(cmp: filecmp.dircmp, rel: str) -> None:
        out.extend(f"{rel}{n}" for n in cmp.diff_files + cmp.left_only if n != "__pycache__")
        for name, sub in cmp.subdirs.items():
            if name != "__pycache__":
                walk(sub, f"{rel}{name}/")

    for folder in ("realtime", "experiments", "docs"):
        walk(filecmp.dircmp(src / folder, ROOT / folder, ignore=["__pycache__"]), f"{folder}/")
    if not filecmp.cmp(src / "README.md", ROOT / "README.md", shallow=False):
        out.append("README.md")
    return sorted(out + [f"tests/{p.name}" for p in (src / "tests").glob("*.py")])


def _run(args: list[str], src: Path, env: dict[str, str]) -> str:
    done = subprocess.run(args, cwd=src, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout


def test_a_planted_family_edits_one_existing_file(tmp_path):
    src, env = _planted_tree(tmp_path)
    (src / "realtime" / "toy.py").write_text(TOY_REALTIME, encoding="utf-8")
    (src / "experiments" / "audit_toy.py").write_text(TOY_AUDIT, encoding="utf-8")
    (src / "tests" / "test_toy.py").write_text(TOY_TEST, encoding="utf-8")
    _add_registry_entry(src / "experiments" / "families.py")
    # Its page, with its quantity's generated section (as a family author regenerates it).
    first = json.loads(_run([sys.executable, "-c", CHECK], src, env))
    page = "# Toy\n\nA planted family.\n\n## Its quantity\n\n" + first["sections"]["toy_reflectance"]
    (src / "docs" / "toy.md").write_text(page, encoding="utf-8")

    assert _changed(src) == [
        "docs/toy.md",
        "experiments/audit_toy.py",
        "experiments/families.py",
        "realtime/toy.py",
        "tests/test_toy.py",
    ]
    got = json.loads(_run([sys.executable, "-c", CHECK], src, env))
    assert "toy" in got["modules"] and got["root"] == 0.5**5  # the realtime root
    ours = {m: [q.name for q in qs] for m, qs in family_quantities().items()}  # the repository's own
    assert set(got["quantities"]) == {*QUANTITIES, "toy_reflectance"}
    assert got["declared"] == {**ours, "toy": ["toy_reflectance"]}
    assert got["families"][0] == "toy" and got["shipped"]["toy"] == ["toy_reflectance"]
    assert missing_quantity_sections(src, got["declared"], got["shipped"], got["sections"]) == []
    assert families_without_a_page(src, got["families"]) == []  # the docs checks
    assert unlisted_pages(src, got["families"]) == []
    listed = _run([sys.executable, "-m", "rtfit", "list"], src, env)
    assert any(line.split()[:2] == ["toy", "Toy:"] for line in listed.splitlines()), listed
    applies = _run([sys.executable, "-m", "rtfit", "audit", "fresnel_spheres", "--list"], src, env)
    assert "toy — " in applies and "a planted family applies to it" in applies, applies
    tests = _run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/test_toy.py"], src, env
    )
    assert "1 passed" in tests


def test_the_planted_tree_is_the_repository_before_the_family(tmp_path):
    """The copy alone, nothing planted, differs from the repository in no file (the check above sees only
    what the family adds)."""
    src, _ = _planted_tree(tmp_path)
    assert _changed(src) == []
