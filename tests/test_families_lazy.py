"""The registry names its families' own studies and benches lazily (`families.LeafFunction`, issue 33):
every one resolves to a function of its leaf module, and importing the registry imports no study module."""

from __future__ import annotations

import subprocess
import sys

from rtfit.experiments.families import FAMILIES, LeafFunction


def test_every_lazy_study_and_bench_resolves_to_a_function_of_its_module():
    lazy = [f for fam in FAMILIES.values() for f in (fam.study, fam.bench) if isinstance(f, LeafFunction)]
    assert len(lazy) >= 14  # the fourteen study modules
    for f in lazy:
        target = f.target
        assert callable(target) and target.__module__ == f"rtfit.experiments.{f.module}"
        assert target.__name__ == f.name


def test_the_registry_imports_no_study_module():
    code = (
        "import sys, rtfit.experiments.families; "
        "print(sorted(m for m in sys.modules if m.startswith('rtfit.') and m.endswith('_study')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
