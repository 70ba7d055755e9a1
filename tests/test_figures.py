"""experiments.figures.case_comparison: the per-case image figure the families share."""

import numpy as np

from rtfit.experiments import figures


def test_case_comparison_writes_links_and_returns_record(tmp_path):
    ref = np.full((6, 8, 3), 0.5)
    doc = {"id": "c1", "label": "case one", "approximations": [{"method": "a"}, {"method": "b"}]}
    panels = [("a", ref * 1.1), ("b", ref * 0.9)]
    rec = figures.case_comparison(
        tmp_path, doc, ref, panels, np.ones((6, 8), bool), error_scale=0.5, caption="case one: text"
    )
    assert rec == {"file": "figures/c1.png", "caption": "case one: text", "section": "results"}
    assert (tmp_path / "figures" / "c1.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [ap["figures"] for ap in doc["approximations"]] == [["figures/c1.png"], ["figures/c1.png"]]
