"""Dependencies flow one way: scenes → reference, realtime → fitting → experiments.

Checked on the source text (imports anywhere in a module, including inside functions)."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
ALLOWED = {
    "scenes": {"scenes"},
    "reference": {"scenes", "reference"},
    "realtime": {"realtime"},
    "fitting": {"realtime", "fitting"},
    "experiments": {"scenes", "reference", "realtime", "fitting", "experiments"},
}
NO_MITSUBA = {"scenes", "realtime", "fitting"}


def _imports(path: Path):
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield node.module


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_imports_follow_the_layering(package):
    bad = []
    for path in sorted((ROOT / package).glob("*.py")):
        for name in _imports(path):
            if name.startswith("rtfit."):
                sub = name.split(".")[1]
                if sub not in ALLOWED[package]:
                    bad.append(f"{path.name}: {name}")
            if package in NO_MITSUBA and name.split(".")[0] == "mitsuba":
                bad.append(f"{path.name}: {name}")
    assert not bad, f"{package} imports outside its layer: {bad}"
