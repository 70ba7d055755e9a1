"""Make the test copies of the quick-suite results: ``python trim.py BASELINE_OUT`` writes
``EXPERIMENT.json`` here for every ``BASELINE_OUT/EXPERIMENT/results.json``, keeping the first three
cases (everything else as it is), so the loader and report tests run on real documents of every family
without a 350 kB file. Key order is kept (the round-trip test relies on it)."""

import json
import sys
from pathlib import Path

CASES = 3

for src in sorted(Path(sys.argv[1]).glob("*/results.json")):
    doc = json.loads(src.read_text(encoding="utf-8"))
    doc["cases"] = doc["cases"][:CASES]
    out = Path(__file__).with_name(f"{src.parent.name}.json")
    out.write_text(json.dumps(doc, ensure_ascii=False) + "\n", encoding="utf-8")
    print(out.name, out.stat().st_size)
