"""experiments.figures.case_comparison: the per-case image figure the families share."""

import numpy as np

from rtfit.experiments import figure_text, figures


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


def _drawn_by_freetype(line: str, size: float) -> np.ndarray:
    """``line`` drawn by matplotlib's FreeType font directly (no memo): the drawing `line_pixels` keeps."""
    import matplotlib
    from matplotlib.font_manager import FontProperties, findfont, get_font
    from matplotlib.ft2font import LoadFlags

    assert matplotlib.rcParams["text.hinting"] == "default"  # (the flags below are its)
    font = get_font(findfont(FontProperties(size=size)))
    font.clear()
    font.set_size(size, figures.PNG_DPI)
    font.set_text(line, 0.0, flags=LoadFlags.DEFAULT)
    font.draw_glyphs_to_bitmap(antialiased=matplotlib.rcParams["text.antialiased"])
    return np.asarray(font.get_image())


def test_memoised_text_is_a_fresh_drawing_and_cannot_be_changed():
    """A memo hit of `line_pixels` is FreeType's drawing of the line; its arrays are read-only, and
    `text_pixels` gives each caller its own array (changing it changes no later drawing)."""
    import pytest

    figure_text.MEMOS[0].clear()
    line = "Ambient cube (Valve: axis samples)"
    first = figure_text.line_pixels(line, 9)
    hit = figure_text.line_pixels(line, 9)
    assert hit[0] is first[0]  # (the memo answered)
    assert np.array_equal(hit[0], _drawn_by_freetype(line, 9))
    for a in (hit[0], hit[2]):
        with pytest.raises(ValueError):
            a[0] = 1
    text = f"{line}\nmean 0.25"
    mine = figures.text_pixels(text, 8)
    mine[:] = 7.0
    again = figures.text_pixels(text, 8)
    figure_text.MEMOS[0].clear()
    assert np.array_equal(again, figures.text_pixels(text, 8))  # memo hit == drawn afresh
    assert again.max() <= 1.0 and again.flags.writeable


def test_wrapping_is_the_greedy_one_measured_word_by_word():
    """`wrap_to_width` breaks each line where the greedy rule does: each line takes words while the line
    drawn afresh (`_drawn_by_freetype`) is at most the width."""

    def greedy(line, size, width):
        out, current = [], ""
        for word in line.split(" "):
            candidate = f"{current} {word}" if current else word
            if current and _drawn_by_freetype(candidate, size).shape[1] > width:
                out.append(current)
                current = word
            else:
                current = candidate
        return "\n".join([*out, current])

    labels = [
        "Seed: per-channel SDF biased by the surface normal (fitted to this scene)",
        "AA: fitted Ω, seed Lambert, cap ∩ hemisphere (fitted to this scene)",
        "Ambient cube (Valve: axis samples) volume, nearest probe",
        "Wrap lighting (fitted to this scene)",
        "error (max 0.0686)",
        "a bb ccc dddd eeeee ffffff ggggggg hhhhhhhh iiiiiiiii",
    ]
    for label in labels:
        for size in (8, 9):
            for width in (30.0, 75.0, 140.0, 214.0, 400.0):
                figure_text.MEMOS[0].clear()
                assert figures.wrap_to_width(label, size, width) == greedy(label, size, width), (label, width)


def test_text_over_an_image_darkens_it_in_turn(tmp_path):
    """A `MosaicFigure` pixel under text is round(255 · v · Π(1 − coverage)) of the image's value v, each
    text over it in turn (here two texts at one place over a uniform grey)."""
    from PIL import Image

    v = 0.4
    fig = figures.MosaicFigure(np.full((40, 60, 3), v), "", 60)
    fig.text(30, 20, "Wg", 9, va="center")
    fig.text(30, 20, "Wg", 9, va="center")
    png = np.asarray(Image.open(fig.save(tmp_path / "t.png")))
    alpha = figures.text_pixels("Wg", 9)
    m = figures.MosaicFigure.MARGIN  # (the content is the image: it starts at the margin)
    th, tw = alpha.shape
    top, left = round((20 + 0.5) * fig.scale - th / 2), round((30 + 0.5) * fig.scale - tw / 2)
    got = png[m + top : m + top + th, m + left : m + left + tw, :3]
    want = np.round(v * (1.0 - alpha) * (1.0 - alpha) * 255).astype(np.uint8)
    assert np.array_equal(got, np.repeat(want[..., None], 3, axis=-1))
    assert png[m, m, :3].tolist() == [round(v * 255)] * 3 and png[0, 0].tolist() == [255] * 3  # grey; white


def test_png_bytes_are_matplotlibs(tmp_path):
    """`png_bytes` writes the PNG ``matplotlib.image.imsave`` writes (RGBA, its dpi, no Software text)."""
    import io

    import matplotlib.image

    rgb = np.random.default_rng(2).integers(0, 256, (7, 11, 3), dtype=np.uint8)
    for dpi, level in ((110, 1), (100, None)):
        buf = io.BytesIO()
        pil_kwargs = None if level is None else {"compress_level": level}
        no_software: dict = {"Software": None}
        matplotlib.image.imsave(buf, rgb, format="png", dpi=dpi, metadata=no_software, pil_kwargs=pil_kwargs)
        assert figures.png_bytes(rgb, dpi, compress_level=level) == buf.getvalue()


def test_rows_up_png_holds_the_same_pixels(tmp_path):
    """`png_rows_up` (the mosaic figures' fast encoding, RGB) decodes to the pixels and resolution of
    `png_bytes` (Pillow's encoding, matplotlib's bytes, RGBA with an opaque alpha), for an enlarged image and
    for noise."""
    import io

    from PIL import Image

    rng = np.random.default_rng(4)
    blocks = np.repeat(np.repeat(rng.integers(0, 256, (5, 7, 3), dtype=np.uint8), 3, axis=0), 4, axis=1)
    for rgb in (blocks, rng.integers(0, 256, (9, 13, 3), dtype=np.uint8), np.zeros((1, 1, 3), np.uint8)):
        fast = Image.open(io.BytesIO(figures.png_rows_up(rgb, figures.PNG_DPI)))
        ref = Image.open(io.BytesIO(figures.png_bytes(rgb, figures.PNG_DPI, compress_level=1)))
        assert fast.mode == "RGB" and ref.mode == "RGBA" and fast.info == ref.info
        assert np.all(np.asarray(ref)[..., 3] == 255)
        assert np.array_equal(np.asarray(fast), np.asarray(ref)[..., :3])


def test_a_tight_layout_figure_is_saved_as_matplotlibs_tight_savefig(tmp_path):
    """`save_figure` of a figure laid out by ``tight_layout`` (its layout engine then a placeholder, which
    `save_figure` drops to spare savefig's unseen draw) writes the bytes of matplotlib's own
    ``savefig(bbox_inches="tight")`` of the same figure with the placeholder kept; log axes and a legend."""
    import io

    plt = figures.pyplot()

    def figure():
        fig, ax = plt.subplots(figsize=(4.6, 3.6))
        x = np.geomspace(0.01, 30, 25)
        for k in range(3):
            ax.plot(x, x ** (0.5 + 0.2 * k), label=f"series {k}")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.legend(fontsize=7)
        fig.tight_layout()
        return fig

    ours = figures.save_figure(figure(), tmp_path / "ours.png").read_bytes()
    fig = figure()
    assert type(fig.get_layout_engine()).__name__ == "PlaceHolderLayoutEngine"
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=figures.PNG_DPI, bbox_inches="tight", pil_kwargs={"compress_level": 1})
    plt.close(fig)
    assert ours == buf.getvalue()


_LOG_FIGURE = """
import io, sys
import numpy as np
import matplotlib
matplotlib.use("Agg", force=True)
import matplotlib.pyplot as plt
fig, axes = plt.subplots(1, 2, figsize=(9.2, 3.6), squeeze=False)
x = np.geomspace(0.01, 300, 25)
for ax in axes[0]:
    for k in range(3):
        ax.plot(x, x ** (0.5 + 0.2 * k), label=f"series $\\\\alpha_{k}$")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_ylabel("RMSE $\\\\sigma$")
    ax.legend(fontsize=7)
fig.tight_layout()
buf = io.BytesIO()
fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight", pil_kwargs={"compress_level": 1})
plt.close(fig)
"""


def test_renderers_share_math_parses_with_matplotlibs_bytes(tmp_path):
    """`figures.pyplot` makes matplotlib's Agg renderers share one math-text parser and a larger cache of its
    parses (`_share_math_parses`; log-axis tick labels are math text): a log-log figure drawn twice parses
    its labels once (the second figure's renderers hit the cache), and its PNG is the bytes that matplotlib
    alone (a fresh process, nothing shared) writes for it."""
    import subprocess
    import sys

    import matplotlib.backends.backend_agg as agg
    import matplotlib.mathtext as mathtext

    code = _LOG_FIGURE.replace("DPI", str(figures.PNG_DPI))
    alone = tmp_path / "alone.png"
    subprocess.run([sys.executable, "-c", code + f"open({str(alone)!r}, 'wb').write(buf.getvalue())\n"],
                   check=True)  # fmt: skip
    figures.pyplot()
    namespace: dict = {}
    exec(code, namespace)
    first = namespace["buf"].getvalue()
    before = mathtext.MathTextParser._parse_cached.cache_info()
    exec(code, namespace)
    after = mathtext.MathTextParser._parse_cached.cache_info()
    assert namespace["buf"].getvalue() == first == alone.read_bytes()
    assert after.misses == before.misses and after.hits > before.hits  # the second figure parsed nothing
    assert after.maxsize == figures.MATH_PARSES
    assert agg.MathTextParser("path") is agg.MathTextParser("path")


def test_figures_written_in_the_background_are_the_plain_writes_bytes(tmp_path, monkeypatch):
    """`pngs_in_background`: the same files, byte for byte, as `MosaicFigure.save` writes without it, all
    present when the block ends; at most ``most`` figures wait (an earlier figure is written before the
    next is handed over); a write's error is raised when the block ends, and a block's own error wins."""
    import pytest

    rng = np.random.default_rng(3)
    images = [rng.uniform(0, 1, (12 + k, 20, 3)) for k in range(5)]

    def figure(k):
        fig = figures.MosaicFigure(images[k], f"figure {k}", 60)
        fig.text(10, 6, f"label {k}", 9, va="center")
        return fig

    plain = [figure(k).save(tmp_path / f"plain{k}.png").read_bytes() for k in range(5)]
    with figures.pngs_in_background(most=2):
        paths = [figure(k).save(tmp_path / f"bg{k}.png") for k in range(5)]
        background = figures._BACKGROUND.get()
        assert background is not None and len(background[1]) <= 2
    assert figures._BACKGROUND.get() is None
    assert [p.read_bytes() for p in paths] == plain

    def failing(path, canvas):
        raise OSError(f"no space left writing {path}")

    monkeypatch.setattr(figures, "_write_png", failing)
    with pytest.raises(OSError, match="no space left"):
        with figures.pngs_in_background():
            figure(0).save(tmp_path / "x.png")
    with pytest.raises(KeyError):  # the block's own error, not the write's
        with figures.pngs_in_background():
            figure(0).save(tmp_path / "y.png")
            raise KeyError("the block's")


def test_a_block_inside_another_uses_its_writer_and_a_forked_helper_writes_its_own(tmp_path):
    """`pngs_in_background` inside another of the same process adds nothing (the outer writer serves it, and
    is still there when the inner block ends); in a process forked inside a block (a `shared_map` helper),
    which has none of its parent's threads, a figure is written at once, the same bytes."""
    import os
    import warnings

    rng = np.random.default_rng(4)
    fig = figures.MosaicFigure(rng.uniform(0, 1, (12, 20, 3)), "figure", 60)
    plain = fig.save(tmp_path / "plain.png").read_bytes()
    with figures.pngs_in_background():
        outer = figures._BACKGROUND.get()
        with figures.pngs_in_background():
            assert figures._BACKGROUND.get() is outer
        assert figures._BACKGROUND.get() is outer and not outer[0]._shutdown
        with warnings.catch_warnings():  # (JAX, where an earlier test of this worker started it, warns)
            warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called", category=RuntimeWarning)
            warnings.simplefilter("ignore", DeprecationWarning)
            pid = os.fork()  # (before the first figure: the writer's thread is not started yet)
        if pid == 0:  # (the helper: its write done before it exits)
            try:
                fig.save(tmp_path / "helper.png")
            finally:
                os._exit(0)
        os.waitpid(pid, 0)
        fig.save(tmp_path / "after-inner.png")
    assert (tmp_path / "after-inner.png").read_bytes() == plain == (tmp_path / "helper.png").read_bytes()
