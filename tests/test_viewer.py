"""The report's image viewer (rtfit.experiments.viewer): saved pixels, the data the page reads, the
single-file report, and the page itself in a real headless browser (Debian's chromium driven by
Playwright; skipped, with the reason, where either is missing: `.ci/run` installs both).

The pixel data are synthetic (a coloured gradient, a disc mask, two approximations) so that the test
runs in seconds; what the page shows is checked against the EXR the experiment would have written,
read back with OpenEXR, not against the viewer's own output.
"""

from __future__ import annotations

import base64
import io
import json
import math
import re
import shutil

import numpy as np
import pytest

from rtfit.experiments import viewer
from rtfit.experiments.report import write_report
from rtfit.fitting import compute_metrics, flip_error_map
from rtfit.reference.io import read_exr

W, H = 48, 40  # not square: a transposed array would show


def _images():
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    ref = np.stack([0.2 + x / W, 0.1 + 0.5 * y / H, 0.3 + 0.2 * (x + y) / (W + H)], axis=-1)
    se = 0.01 * ref
    mask = (x - W / 2) ** 2 + (y - H / 2) ** 2 < (0.45 * H) ** 2
    rng = np.random.default_rng(7)
    a1 = ref * 1.1
    a2 = ref + 0.02 * rng.standard_normal(ref.shape)
    return ref, se, mask, {"brighter": a1, "noisy.v2": a2}


def _doc(cases) -> dict:
    return {
        "schema": "rtfit.results/1",
        "experiment": "viewer-test",
        "title": "Viewer test",
        "summary": "Synthetic images.",
        "created": "2026-12-01T00:00:00+00:00",
        "config": {"quick": True},
        "versions": {"rtfit": "0.1.0"},
        "device": "CPU",
        "cases": [
            {
                "id": cid,
                "label": f"case {cid}",
                "approximations": [
                    {"method": "brighter", "label": "10 % brighter", "metrics": {"rmse": {"value": 0.1}}},
                    {"method": "noisy.v2", "label": "noisy", "metrics": {"rmse": {"value": 0.02}}},
                ],
            }
            for cid in cases
        ],
        "figures": [{"file": "figures/tiny.png", "caption": "A tiny figure."}],
    }


@pytest.fixture
def report_dir(tmp_path):
    """An experiment directory as a run leaves it: results.json, a figure, pixels/ of two cases."""
    import matplotlib.image

    d = tmp_path / "viewer-test"
    ref, se, mask, approx = _images()
    for cid in ("c0", "c1/odd id"):
        viewer.save_case_pixels(d, cid, ref, se, approx, mask)
    (d / "figures").mkdir()
    matplotlib.image.imsave(d / "figures" / "tiny.png", np.zeros((4, 4, 3)))
    (d / "results.json").write_text(json.dumps(_doc(["c0", "c1/odd id"])), encoding="utf-8")
    write_report(d, single_file=True)
    return d


# ------------------------------------------------------------------------------------ files and data
def test_saved_pixels_round_trip_as_float32(tmp_path):
    ref, se, mask, approx = _images()
    exr = viewer.save_case_pixels(tmp_path, "c0", ref, se, approx, mask)
    assert exr == tmp_path / "pixels" / "c0.exr"
    ch = read_exr(exr)  # independent reader: the EXR's own channels
    assert np.array_equal(ch["R"], ref[..., 0].astype(np.float32))
    assert np.array_equal(ch["stderr.B"], se[..., 2].astype(np.float32))
    assert np.array_equal(ch["mask"] > 0.5, mask)
    meta = json.loads((tmp_path / "pixels" / "c0.json").read_text())
    assert [a["method"] for a in meta["approximations"]] == ["brighter", "noisy.v2"]
    layer = meta["approximations"][1]["layer"]
    assert "." not in layer  # an EXR layer separator inside a method id would split the layer
    assert np.array_equal(ch[f"{layer}.G"], approx["noisy.v2"][..., 1].astype(np.float32))
    px = viewer.load_case_pixels(tmp_path, "c0")
    assert px is not None and np.array_equal(
        px.approximations["brighter"], approx["brighter"].astype(np.float32)
    )


def test_grey_images_are_stored_as_three_equal_channels(tmp_path):
    ref = np.linspace(0, 1, 30 * 25).reshape(25, 30)
    viewer.save_case_pixels(tmp_path, "g", ref, 0.1 * ref, {"m": ref})
    px = viewer.load_case_pixels(tmp_path, "g")
    assert px is not None and px.reference.shape == (25, 30, 3) and px.mask.all()
    assert np.array_equal(px.reference[..., 0], px.reference[..., 2])


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"reference": np.zeros((4, 4, 2))}, "expected an image"),
        ({"stderr": np.zeros((5, 4, 3))}, "differs from the reference"),
        ({"stderr": -np.ones((4, 4, 3))}, "negative"),
        ({"approximations": {"m": np.full((4, 4, 3), np.nan)}}, "non-finite"),
        ({"mask": np.ones((4, 4))}, "mask must be boolean"),
    ],
)
def test_bad_pixels_are_refused_naming_the_case(tmp_path, change, message):
    args = {
        "reference": np.ones((4, 4, 3)),
        "stderr": np.zeros((4, 4, 3)),
        "approximations": {},
        "mask": None,
    }
    args.update(change)
    with pytest.raises(ValueError, match=message) as e:
        viewer.save_case_pixels(tmp_path, "bad", **args)
    assert "'bad'" in str(e.value)
    assert not (tmp_path / "pixels" / "bad.exr").exists()


def test_flip_map_mean_is_the_flip_metric():
    ref, se, mask, approx = _images()
    fmap = flip_error_map(approx["brighter"], ref, mask)
    assert fmap.shape == (H, W) and fmap.min() >= 0 and fmap.max() <= 1
    value = compute_metrics(approx["brighter"], ref, se, mask, names=("flip",))["flip"].value
    assert float(np.mean(fmap[mask])) == pytest.approx(value, rel=1e-12)  # same map, same mean
    with pytest.raises(ValueError, match="at least"):
        flip_error_map(ref[:10, :10], ref[:10, :10])


def _decode(text: str, case: str) -> dict:
    m = re.fullmatch(
        r"\(window\.RTFIT_VIEWER_DATA=window\.RTFIT_VIEWER_DATA\|\|\{\}\)\[(.+?)\]=(.*);\n", text
    )
    assert m is not None and json.loads(m.group(1)) == case
    return json.loads(m.group(2))


def test_viewer_data_are_the_exr_floats(report_dir):
    """The page's data script holds exactly the float32 values of the EXR (little-endian, row-major)."""
    layers = _decode((report_dir / "viewer" / "data" / "c0.js").read_text(), "c0")
    ch = read_exr(report_dir / "pixels" / "c0.exr")
    ref = np.frombuffer(base64.b64decode(layers["reference"]), "<f4").reshape(H, W, 3)
    assert np.array_equal(ref, np.stack([ch[c] for c in "RGB"], -1))
    flip = np.frombuffer(base64.b64decode(layers["flip/brighter"]), "<f4").reshape(H, W)
    assert 0 < flip.max() <= 1
    html = (report_dir / "report.html").read_text()
    assert 'id="viewer"' in html and 'src="viewer/viewer.js"' in html
    assert html.index('id="viewer"') < html.index("<footer>")
    assert (report_dir / "pixels" / "c0" / "reference.png").is_file()


def test_report_without_pixels_has_no_viewer(tmp_path):
    d = tmp_path / "plain"
    d.mkdir()
    doc = _doc(["c0"])
    doc.pop("figures")
    (d / "results.json").write_text(json.dumps(doc), encoding="utf-8")
    write_report(d)
    assert 'id="viewer"' not in (d / "report.html").read_text()
    assert not (d / "viewer").exists()


def test_a_damaged_pixels_file_costs_only_its_case(report_dir, caplog):
    (report_dir / "pixels" / "c0.exr").write_bytes(b"not an EXR")
    write_report(report_dir)
    page = (report_dir / "report.html").read_text()
    cases = json.loads(re.search(r'id="rtfit-viewer-manifest">(.*?)</script>', page).group(1))["cases"]
    assert [c["id"] for c in cases] == ["c1/odd id"]
    assert not (report_dir / "viewer" / "data" / "c0.js").exists()  # stale data removed
    assert "case c0 left out" in caplog.text


def test_single_file_refers_to_no_other_file(report_dir):
    page = (report_dir / viewer.SINGLE_FILE).read_text()
    assert not re.search(r'<(script|img)\b[^>]*\bsrc="(?!data:)', page)
    assert not re.search(r"<link\b[^>]*\bhref=", page)
    assert "data:image/png;base64," in page and "RTFIT_VIEWER_DATA" in page


# --------------------------------------------------------------------------------- real browser
def _browser():
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.skip("no chromium on PATH (Debian: apt-get install chromium; .ci/run installs it)")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("playwright is not installed (it is in the test extra: pip install -e '.[test]')")
    return chromium, sync_playwright


def _open(pw, chromium: str, url: str):
    browser = pw.chromium.launch(executable_path=chromium, args=["--no-sandbox"])
    page = browser.new_page(viewport={"width": 1200, "height": 900})
    errors: list[str] = []
    page.on("console", lambda m: errors.append(f"console {m.type}: {m.text}") if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(f"page error: {e}"))
    page.goto(url)
    page.wait_for_selector(".rtfit-viewer[data-state=ready]", timeout=30_000)
    page.locator(".rtfit-viewer canvas.rv-canvas").scroll_into_view_if_needed()
    return browser, page, errors


def _canvas(page) -> np.ndarray:
    """The viewer's canvas read back as PNG (canvas.toDataURL), decoded to (H, W, 4) uint8."""
    import matplotlib.image

    url = page.evaluate("document.querySelector('.rv-canvas').toDataURL('image/png')")
    png = base64.b64decode(url.split(",", 1)[1])
    return np.round(matplotlib.image.imread(io.BytesIO(png), format="png") * 255).astype(np.uint8)


def _numbers(text: str) -> list[float]:
    return [float(t) for t in re.findall(r"[-+]?\d+(?:\.\d*)?(?:e[-+]?\d+)?", text.replace("−", "-"))]


def test_viewer_in_headless_chromium(report_dir):
    chromium, sync_playwright = _browser()
    ch = read_exr(report_dir / "pixels" / "c0.exr")
    with sync_playwright() as pw:
        browser, page, errors = _open(pw, chromium, (report_dir / "report.html").as_uri())
        try:
            v = "RTFIT_VIEWER.instances[0]"
            assert page.evaluate(f"{v}.state.a") == "reference"
            assert page.evaluate(f"{v}.state.b") == "approx/brighter"

            # The wipe, dragged with the mouse from its line to the left edge, changes pixels.
            before = _canvas(page)
            wipe = page.evaluate(f"{v}.state.wipe")
            start = page.evaluate(f"{v}.clientPoint({wipe * W - 0.5}, {H / 2})")
            end = page.evaluate(f"{v}.clientPoint(2, {H / 2})")
            page.mouse.move(*start)
            page.mouse.down()
            page.mouse.move(*end, steps=5)
            page.mouse.up()
            assert page.evaluate(f"{v}.state.wipe") < 0.1
            after_wipe = _canvas(page)
            assert np.count_nonzero(np.any(after_wipe != before, axis=-1)) > 500

            # The exposure slider brightens the image: +2 EV over the automatic exposure.
            ev = page.evaluate(f"{v}.state.ev")
            page.locator(".rv-ev").fill(str(ev + 2))
            assert page.evaluate(f"{v}.state.ev") == pytest.approx(ev + 2)
            after_ev = _canvas(page)
            changed = np.any(after_ev != after_wipe, axis=-1)
            assert np.count_nonzero(changed) > 500
            assert (
                after_ev[..., :3][changed].astype(int).sum() > after_wipe[..., :3][changed].astype(int).sum()
            )
            assert "2^" in page.locator(".rv-bars").inner_text()  # the colour bar states the exposure

            # The readout shows the reference value of a known pixel, as stored in the EXR.
            x, y = 31, 17
            page.mouse.move(*page.evaluate(f"{v}.clientPoint({x}, {y})"))
            assert f"x = {x}, y = {y}" in page.locator(".rv-where").inner_text()
            shown = _numbers(page.locator(".rv-ref-value").inner_text())
            sigma = _numbers(page.locator(".rv-ref-sigma").inner_text())
            # six significant digits shown: 5e-6 relative
            assert shown == pytest.approx([float(ch[c][y, x]) for c in "RGB"], rel=5e-6)
            assert sigma == pytest.approx([float(ch[f"stderr.{c}"][y, x]) for c in "RGB"], rel=5e-6)

            # A false-colour image and its scale; another case loads from its data script.
            page.locator(".rv-a").select_option("signed/brighter")
            assert "signed error" in page.locator(".rv-bars").inner_text()
            page.evaluate(f"{v}.setCase(1)")
            page.wait_for_selector(".rtfit-viewer[data-state=ready]")
            assert errors == []
        finally:
            browser.close()


def test_single_file_report_in_headless_chromium(report_dir, tmp_path):
    """report.single.html alone in an empty folder: the viewer still loads (nothing else to read)."""
    chromium, sync_playwright = _browser()
    alone = tmp_path / "mail"
    alone.mkdir()
    shutil.copy(report_dir / viewer.SINGLE_FILE, alone / "report.html")
    with sync_playwright() as pw:
        browser, page, errors = _open(pw, chromium, (alone / "report.html").as_uri())
        try:
            page.evaluate("RTFIT_VIEWER.instances[0].setCase(1)")
            page.wait_for_selector(".rtfit-viewer[data-state=ready]")
            loaded = page.evaluate("Array.from(document.images).every(i => i.complete && i.naturalWidth > 0)")
            assert loaded and errors == []
            assert not math.isnan(page.evaluate("RTFIT_VIEWER.instances[0].state.ev"))
        finally:
            browser.close()


def test_primed_flip_maps_are_those_the_viewer_asks_for(tmp_path):
    """`prime_case_flip` (run beside an audit's figures) leaves in the memo every ꟻLIP map the viewer of that
    case then needs: priming the viewer's own inputs afterwards computes none."""
    from rtfit.fitting import prime_flip

    ref, se, mask, approx = _images()
    approx = {k: v * 1.0001 for k, v in approx.items()}  # (maps not in the memo from other tests)
    viewer.save_case_pixels(tmp_path, "p", ref, se, approx, mask)
    viewer.prime_case_flip(tmp_path, "p")
    px = viewer.load_case_pixels(tmp_path, "p")
    assert px is not None
    assert prime_flip(list(px.approximations.values()), px.reference, px.stderr, px.mask, floor_draws=0) == 0
    viewer.prime_case_flip(tmp_path, "missing")  # no pixels: nothing to do, no error


def test_viewer_flip_thread_starts_only_where_the_audit_left_flip_out(tmp_path):
    """`audit_output.viewer_flip_thread`: where every row's metrics hold ``flip``, the audit's own maps are
    the viewer's (its float32 pixels give the same exposures) and no thread starts: priming the viewer's
    inputs then computes no map. Where the rows' metrics leave ꟻLIP out, the thread computes the viewer's
    maps beside the figures (afterwards, none is left to compute)."""
    from types import SimpleNamespace

    from rtfit.experiments.audit_output import viewer_flip_thread
    from rtfit.fitting import prime_flip

    ref, se, mask, approx = _images()
    for scale, names, starts in ((1.0002, ("rmse", "flip"), False), (1.0003, ("rmse",), True)):
        images = {k: v * scale for k, v in approx.items()}  # (maps not in the memo from other tests)
        viewer.save_case_pixels(tmp_path, "p", ref, se, images, mask)
        rows = {
            k: SimpleNamespace(metrics=compute_metrics(v, ref, se, mask, names=names))
            for k, v in images.items()
        }
        audit = SimpleNamespace(
            cases=[SimpleNamespace(id="p", reference=SimpleNamespace(mean=ref))], outcomes={"p": rows}
        )
        thread = viewer_flip_thread(tmp_path, audit)
        assert (thread is not None) == starts
        if thread is not None:
            thread.join()
        px = viewer.load_case_pixels(tmp_path, "p")
        assert px is not None
        assert (
            prime_flip(list(px.approximations.values()), px.reference, px.stderr, px.mask, floor_draws=0) == 0
        )
