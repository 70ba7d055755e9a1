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


def test_colour_bar_ticks_are_matplotlibs(tmp_path):
    """The ticks `MosaicFigure` draws beside its bar: those matplotlib's own colour bar of that length has."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure

    for vmin, vmax in [(-0.234, 0.234), (0.0, 1.0), (-2e-6, 2e-6)]:
        fig = Figure(figsize=(1.0, 3.0), dpi=figures.PNG_DPI)
        cax = fig.add_axes((0.1, 0.1, 0.2, 0.8))
        bar = fig.colorbar(ScalarMappable(norm=Normalize(vmin, vmax), cmap="RdBu_r"), cax=cax)
        fig.canvas.draw()
        length_pt = cax.get_window_extent().height / figures.PNG_DPI * 72
        locs, labels, offset = figures.colour_bar_ticks(vmin, vmax, length_pt, 10)
        shown = [
            (v, t.get_text())
            for v, t in zip(bar.get_ticks(), cax.get_yticklabels(), strict=True)
            if vmin - 1e-9 * vmax <= v <= vmax + 1e-9 * vmax
        ]  # fmt: skip (the bar shows those in range)
        assert np.allclose(locs, [v for v, _ in shown], rtol=0, atol=1e-12 * vmax)
        assert labels == [t for _, t in shown]
        assert offset == cax.yaxis.get_major_formatter().get_offset()  # (the text above the bar)


def test_image_comparison_shows_each_pixel_as_a_block(tmp_path):
    """Each tile of the mosaic figure holds its image's sRGB pixels, each a block of figure pixels."""
    import matplotlib.image

    rng = np.random.default_rng(1)
    ref = rng.uniform(0.1, 1.0, (4, 5, 3))
    path = figures.image_comparison(
        tmp_path / "f.png", ref, [("a", ref)], np.ones((4, 5), bool), 1.0, "t", 1.0
    )
    png = matplotlib.image.imread(path)[..., :3]
    want = np.round(figures.srgb(ref) * 255) / 255
    # find the reference tile: the block whose colour is its first pixel's, then sample each block's centre
    ys, xs = np.nonzero(np.all(np.abs(png - want[0, 0]) < 1e-6, axis=-1))
    y0, x0 = ys.min(), xs.min()
    s = figures.MOSAIC_COLUMN_PX / (5 + figures.mosaic_spacing(4, 5)[0])
    for i in range(4):
        for j in range(5):
            got = png[y0 + int((i + 0.5) * s), x0 + int((j + 0.5) * s)]
            assert np.allclose(got, want[i, j], atol=1e-6)


def test_labels_wrap_at_spaces_to_the_tile_width():
    label = "Schlick, fitted F0 and exponent (fitted to this scene)"
    width = 0.5 * figures.text_pixels(label, 9).shape[1]
    wrapped = figures.wrap_to_width(label, 9, width)
    lines = wrapped.split("\n")
    assert len(lines) >= 2 and " ".join(lines) == label  # only spaces became line breaks
    assert all(figures.text_pixels(line, 9).shape[1] <= width for line in lines)
    assert figures.wrap_to_width("Schlick\nmean 0.03", 9, 1e4) == "Schlick\nmean 0.03"  # fits: unchanged
    assert figures.wrap_to_width("Lazányi–Szirmay-Kalos", 9, 5.0) == "Lazányi–Szirmay-Kalos"  # one word
