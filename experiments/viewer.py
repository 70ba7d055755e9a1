"""The image viewer of every report: per-pixel reference, approximations and their error maps.

An experiment whose cases are images saves, per case, the arrays its metrics were computed from
(:func:`save_case_pixels`); the report generator (:func:`write_viewer`, called by
``report.write_report``) turns them into an interactive viewer placed at the end of ``report.html``.
Everything the viewer shows is derived from ``results.json`` and these saved arrays alone, so
``rtfit report DIR`` rebuilds it without rerunning anything. Layout (``docs/viewer.md``)::

    EXPERIMENT/
      pixels/CASE.exr          float32 EXR: R,G,B reference mean; stderr.R/G/B the uncertainty the
                               metrics used; mask (1 inside the comparison mask); LAYER.R/G/B each
                               approximation (written by the experiment, the viewer's only input)
      pixels/CASE.json         "rtfit.pixels/1": case id, size, and method id → EXR layer
      pixels/CASE/NAME.png     sRGB previews (reference and approximations, one exposure per case)
      viewer/viewer.js, .css   the viewer (plain JavaScript and CSS, copied from viewer_assets/)
      viewer/data/CASE.js      the float data for the page: base64 little-endian float32 arrays,
                               assigned to a global by a <script> (works from file://, where
                               fetch() of local files is blocked)
      report.single.html       with ``single_file``: the report with every figure, style, script and
                               the data embedded (one file to mail)

Derived maps (computed by the page from the float data, per channel or on the Rec. 709 luminance
Y = 0.2126 R + 0.7152 G + 0.0722 B): signed error Δ = x − r; relative error Δ / sqrt(r² + ε) with
ε = ``REL_MSE_EPS`` (its mean square over the mask is the report's relMSE); z = Δ / σ (σ the saved
stderr). The ꟻLIP map is computed here (:func:`rtfit.fitting.flip_error_map`, the flip metric's
exposure range and mask), as it needs ꟻLIP's own filters.
"""

from __future__ import annotations

import base64
import html
import json
import logging
import re
import shutil
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rtfit.fitting import REL_MSE_EPS, flip_error_map, prime_flip
from rtfit.reference.io import atomic_write_bytes, atomic_write_json, atomic_write_text, read_exr, write_exr

from .figures import png_bytes
from .records import Results

__all__ = [
    "PIXELS_DIR",
    "PIXELS_FORMAT",
    "SINGLE_FILE",
    "VIEWER_DIR",
    "CasePixels",
    "case_file_stem",
    "load_case_pixels",
    "prime_case_flip",
    "save_case_pixels",
    "single_file_html",
    "write_viewer",
]

PIXELS_DIR = "pixels"
VIEWER_DIR = "viewer"
SINGLE_FILE = "report.single.html"
PIXELS_FORMAT = "rtfit.pixels/1"
log = logging.getLogger(__name__)
ASSETS = Path(__file__).resolve().parent / "viewer_assets"
ASSET_FILES = ("viewer.js", "viewer.css")
_SAFE = re.compile(r"[^A-Za-z0-9_.-]")
COLORMAPS = {"diverging": "RdBu_r", "flip": "magma", "sequential": "viridis"}


def case_file_stem(case_id: str) -> str:
    """File name stem for a case id: characters other than ``A-Za-z0-9_.-`` become ``_``."""
    stem = _SAFE.sub("_", case_id).lstrip(".")
    return stem or "case"


def _layer_name(method: str, taken: set[str]) -> str:
    base = _SAFE.sub("_", method).replace(".", "_") or "approx"
    if base in ("R", "G", "B", "stderr", "mask"):
        base = f"approx_{base}"
    name, k = base, 2
    while name in taken:
        name, k = f"{base}_{k}", k + 1
    taken.add(name)
    return name


def _as_rgb(a, what: str, shape=None) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=-1)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"{what}: expected an image (H, W) or (H, W, 3), got shape {a.shape}")
    if shape is not None and a.shape != shape:
        raise ValueError(f"{what}: shape {a.shape} differs from the reference's {shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what}: {int(np.sum(~np.isfinite(a)))} non-finite values")
    if np.any(np.abs(a) > np.finfo(np.float32).max):
        raise ValueError(f"{what}: values beyond the float32 range")
    return a


def save_case_pixels(
    out_dir,
    case_id: str,
    reference,
    stderr,
    approximations: Mapping[str, np.ndarray],
    mask=None,
) -> Path:
    """Save one case's per-pixel data for the report's viewer: ``OUT/pixels/CASE.exr`` and ``.json``.

    ``reference``: the reference mean, ``stderr``: the uncertainty the metrics compared against (same
    units), ``approximations``: method id (as in the case's ``approximations[].method``) → image,
    ``mask``: boolean (H, W) comparison mask (default all). Images are (H, W, 3) linear RGB or (H, W)
    (stored as three equal channels), finite, in float32 range; they are stored as float32.
    Returns the EXR path. Raises ValueError (naming the case) on a bad shape or value.
    """
    where = f"pixels of case {case_id!r}"
    ref = _as_rgb(reference, f"{where}: reference")
    se = _as_rgb(stderr, f"{where}: stderr", ref.shape)
    if np.any(se < 0):
        raise ValueError(f"{where}: stderr has negative values")
    m = np.ones(ref.shape[:2], bool) if mask is None else np.asarray(mask)
    if m.dtype != np.bool_ or m.shape != ref.shape[:2]:
        raise ValueError(f"{where}: mask must be boolean of shape {ref.shape[:2]}, got {m.dtype} {m.shape}")
    channels: dict[str, np.ndarray] = {"RGB": ref, "stderr": se, "mask": m.astype(np.float32)}
    taken: set[str] = set()
    layers = []
    for method, img in approximations.items():
        layer = _layer_name(method, taken)
        channels[layer] = _as_rgb(img, f"{where}: approximation {method!r}", ref.shape)
        layers.append({"method": method, "layer": layer})
    folder = Path(out_dir) / PIXELS_DIR
    stem = case_file_stem(case_id)
    exr = write_exr(folder / f"{stem}.exr", channels)
    atomic_write_json(
        folder / f"{stem}.json",
        {
            "format": PIXELS_FORMAT,
            "case": case_id,
            "exr": f"{stem}.exr",
            "width": int(ref.shape[1]),
            "height": int(ref.shape[0]),
            "reference": "R,G,B",
            "stderr": "stderr.R,stderr.G,stderr.B",
            "mask": "mask",
            "approximations": layers,
        },
    )
    return exr


@dataclass(frozen=True)
class CasePixels:
    """One case's saved arrays (float32): ``reference``, ``stderr`` (H, W, 3), ``mask`` (H, W) bool,
    ``approximations`` method id → (H, W, 3)."""

    case: str
    reference: np.ndarray
    stderr: np.ndarray
    mask: np.ndarray
    approximations: dict[str, np.ndarray]


def _group(ch: dict[str, np.ndarray], prefix: str) -> np.ndarray:
    p = f"{prefix}." if prefix else ""
    return np.stack([ch[f"{p}{c}"] for c in "RGB"], axis=-1)


def load_case_pixels(directory, case_id: str) -> CasePixels | None:
    """The arrays :func:`save_case_pixels` wrote for ``case_id`` under ``directory`` (an experiment's
    output directory), or None when there are none. Raises ValueError on a malformed file."""
    folder = Path(directory) / PIXELS_DIR
    meta_path = folder / f"{case_file_stem(case_id)}.json"
    if not meta_path.is_file():
        return None
    meta = json.loads(meta_path.read_text(encoding="utf-8"))
    if meta.get("format") != PIXELS_FORMAT or meta.get("case") != case_id:
        raise ValueError(f"{meta_path}: not {PIXELS_FORMAT} for case {case_id!r}")
    try:
        ch = read_exr(folder / meta["exr"])
        return CasePixels(
            case_id,
            _group(ch, ""),
            _group(ch, "stderr"),
            ch["mask"] > 0.5,
            {a["method"]: _group(ch, a["layer"]) for a in meta["approximations"]},
        )
    except (KeyError, OSError, RuntimeError) as e:
        raise ValueError(f"{meta_path}: cannot read its pixels ({type(e).__name__}: {e})") from None


# ------------------------------------------------------------------------------------------ building
def _b64(a: np.ndarray, dtype) -> str:
    return base64.b64encode(
        np.ascontiguousarray(a, dtype=np.dtype(dtype).newbyteorder("<")).tobytes()
    ).decode("ascii")


def _script_json(obj) -> str:
    """JSON safe inside a <script> element (no ``</``, no HTML comment openers)."""
    return (
        json.dumps(obj, ensure_ascii=False, separators=(",", ":"))
        .replace("</", "<\\/")
        .replace("<!--", "<\\!--")
    )


def _colormaps() -> dict[str, list[list[int]]]:
    import matplotlib

    out = {}
    for key, name in COLORMAPS.items():
        lut = matplotlib.colormaps[name](np.linspace(0.0, 1.0, 256))[:, :3]
        out[key] = np.round(lut * 255).astype(int).tolist()
    return out


def _srgb8(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear, 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(s * 255).astype(np.uint8)


def _png(rgb8: np.ndarray) -> bytes:
    """PNG bytes as ``matplotlib.image.imsave(buf, rgb8, format="png", metadata={"Software": None})`` writes
    them (its default 100 dpi and compression; `figures.png_bytes`)."""
    return png_bytes(rgb8, 100)


def _exposure(ref: np.ndarray, mask: np.ndarray) -> float:
    """Preview scale: 1 / the 99.5th percentile of the masked reference (1 when that is not positive)."""
    vals = ref[mask] if mask.any() else ref.reshape(-1, 3)
    p = float(np.percentile(vals, 99.5)) if vals.size else 0.0
    return 1.0 / p if p > 0 else 1.0


def prime_case_flip(directory, case_id: str) -> None:
    """Compute the ꟻLIP maps the viewer of ``case_id`` will show (its saved pixels under ``directory``, as
    `write_viewer` reads them) into the map memo of `rtfit.fitting.prime_flip`, where `write_viewer` finds
    them: `audit_output.write_audit` runs this beside the figures (ꟻLIP releases the GIL). A case without
    pixels or with unreadable ones is left to `write_viewer` (which says why)."""
    try:
        px = load_case_pixels(directory, case_id)
    except ValueError:
        return
    if px is not None:
        prime_flip(list(px.approximations.values()), px.reference, px.stderr, px.mask, floor_draws=0)


def _build_case(directory: Path, case, px: CasePixels) -> tuple[dict, str, list[Path]]:
    """Manifest entry, data script text and preview paths of one case."""
    stem = case_file_stem(case.id)
    labels = {ap.method: ap.display for ap in case.approximations}
    layers = {
        "reference": _b64(px.reference, np.float32),
        "stderr": _b64(px.stderr, np.float32),
        "mask": _b64(px.mask, np.uint8),
    }
    approx, flip_note = [], None
    # Every row's ꟻLIP map together (`prime_flip`, no noise-floor draws), where the memo does not
    # hold it yet: the pixels read back as float32 are what ꟻLIP saw in the audit, with the same exposures
    # (`flip_exposures` rounds the reference to float32), so the audit's maps are found by content.
    prime_flip(list(px.approximations.values()), px.reference, px.stderr, px.mask, floor_draws=0)
    for method, img in px.approximations.items():
        layers[f"approx/{method}"] = _b64(img, np.float32)
        try:
            fmap = flip_error_map(img, px.reference, px.mask)
            layers[f"flip/{method}"] = _b64(fmap, np.float32)
            flip_mean = float(np.mean(fmap[px.mask]))
        except ValueError as e:
            flip_note, flip_mean = str(e), None
        approx.append({"method": method, "label": labels.get(method, method), "flip_mean": flip_mean})
    scale = _exposure(px.reference, px.mask)
    previews = [
        atomic_write_bytes(
            directory / PIXELS_DIR / stem / f"{case_file_stem(name)}.png", _png(_srgb8(img * scale))
        )
        for name, img in [("reference", px.reference), *px.approximations.items()]
    ]
    entry = {
        "id": case.id,
        "label": case.label,
        "width": int(px.reference.shape[1]),
        "height": int(px.reference.shape[0]),
        "script": f"{VIEWER_DIR}/data/{stem}.js",
        "exr": f"{PIXELS_DIR}/{stem}.exr",
        "mask_pixels": int(px.mask.sum()),
        "preview_exposure_ev": float(np.log2(scale)),
        "approximations": approx,
        "flip_note": flip_note,
    }
    store = "(window.RTFIT_VIEWER_DATA=window.RTFIT_VIEWER_DATA||{})"
    data = f"{store}[{_script_json(case.id)}]={_script_json(layers)};\n"
    return entry, data, previews


def _section(manifest: dict) -> str:
    return (
        '<section class="rtfit-viewer-section">\n<h2 id="viewer">Image viewer</h2>\n'
        '<p class="rtfit-viewer-intro">Every case with per-pixel data: the reference, each approximation, '
        "and per approximation its signed error Δ = x − r, relative error Δ/√(r² + ε), z = Δ/σ and ꟻLIP map. "
        "Pick A and B and drag the wipe line; wheel to zoom, drag to pan, double-click to fit; the readout "
        "follows the pointer. Float data as EXR in <code>pixels/</code>.</p>\n"
        f'<link rel="stylesheet" href="{VIEWER_DIR}/viewer.css">\n'
        '<div class="rtfit-viewer" data-manifest="rtfit-viewer-manifest"><noscript>The viewer needs '
        "JavaScript; the float data are in <code>pixels/*.exr</code>.</noscript></div>\n"
        f'<script type="application/json" id="rtfit-viewer-manifest">{_script_json(manifest)}</script>\n'
        f'<script src="{VIEWER_DIR}/viewer.js"></script>\n</section>\n'
    )


def _insert(page: str, section: str) -> str:
    """The section before the footer, and a contents entry for it."""
    page = page.replace("</ol></nav>", '<li><a href="#viewer">Image viewer</a></li></ol></nav>', 1)
    i = page.rfind("<footer>")
    i = i if i >= 0 else page.rfind("</main>")
    return page[:i] + section + page[i:]


def write_viewer(directory, results: Results, texts: dict[str, str], single_file: bool = False) -> list[Path]:
    """Build the viewer of ``directory`` from ``results`` and its ``pixels/``: write ``viewer/`` and the
    PNG previews, and add the viewer's section to ``texts["report.html"]`` (in place). With
    ``single_file``, also write ``report.single.html`` (everything embedded). A report without pixel
    data is left unchanged (but ``single_file`` still embeds its figures). Returns the written paths."""
    directory = Path(directory)
    written: list[Path] = []
    cases, scripts = [], {}
    for case in results.cases:
        try:
            px = load_case_pixels(directory, case.id)
        except ValueError as e:  # a damaged pixels file costs its case's viewer, not the report
            log.warning("viewer: case %s left out: %s", case.id, e)
            continue
        if px is None:
            continue
        entry, data, previews = _build_case(directory, case, px)
        cases.append(entry)
        scripts[entry["script"]] = data
        written += previews
    data_dir = directory / VIEWER_DIR / "data"
    if data_dir.is_dir():  # stale data of cases no longer in the results
        for f in data_dir.glob("*.js"):
            if f"{VIEWER_DIR}/data/{f.name}" not in scripts:
                f.unlink()
    if cases:
        manifest = {
            "format": "rtfit.viewer/1",
            "experiment": results.experiment,
            "rel_eps": REL_MSE_EPS,
            "colormaps": _colormaps(),
            "cases": cases,
        }
        for name, text in scripts.items():
            written.append(atomic_write_text(directory / name, text))
        for name in ASSET_FILES:
            written.append(
                atomic_write_text(directory / VIEWER_DIR / name, (ASSETS / name).read_text(encoding="utf-8"))
            )
        texts["report.html"] = _insert(texts["report.html"], _section(manifest))
    elif (directory / VIEWER_DIR).is_dir():
        shutil.rmtree(directory / VIEWER_DIR)
    if single_file:
        written.append(
            atomic_write_text(
                directory / SINGLE_FILE, single_file_html(texts["report.html"], directory, scripts)
            )
        )
    return written


# --------------------------------------------------------------------------------------- single file
_IMG = re.compile(r'(<img\b[^>]*?\bsrc=")([^"]+)(")')
_CSS_LINK = re.compile(r'<link rel="stylesheet" href="([^"]+)">')
_SCRIPT = re.compile(r'<script src="([^"]+)"></script>')
_MIME = {
    ".png": "image/png",
    ".jpg": "image/jpeg",
    ".jpeg": "image/jpeg",
    ".svg": "image/svg+xml",
    ".gif": "image/gif",
}


def _local(directory: Path, ref: str) -> Path | None:
    ref = html.unescape(ref)
    if re.match(r"^[a-z][a-z0-9+.-]*:", ref, re.I) or ref.startswith("/") or ".." in ref.split("/"):
        return None
    p = directory / ref
    return p if p.is_file() else None


def single_file_html(page: str, directory, scripts: Mapping[str, str] | None = None) -> str:
    """``page`` with its local images as data: URIs, its local style sheets and scripts inline, and the
    viewer's data scripts (``scripts``: relative path → text) inline before the viewer's code, so that the
    page needs no other file."""
    directory = Path(directory)

    def img(m: re.Match) -> str:
        p = _local(directory, m.group(2))
        if p is None:
            return m.group(0)
        mime = _MIME.get(p.suffix.lower(), "application/octet-stream")
        return (
            f"{m.group(1)}data:{mime};base64,{base64.b64encode(p.read_bytes()).decode('ascii')}{m.group(3)}"
        )

    def css(m: re.Match) -> str:
        p = _local(directory, m.group(1))
        return m.group(0) if p is None else f"<style>{p.read_text(encoding='utf-8')}</style>"

    def script(m: re.Match) -> str:
        p = _local(directory, m.group(1))
        if p is None:
            return m.group(0)
        code = p.read_text(encoding="utf-8").replace("</script", "<\\/script")
        data = "".join(f"<script>{t}</script>\n" for t in (scripts or {}).values())
        return f"{data}<script>{code}</script>"

    page = _IMG.sub(img, page)
    page = _CSS_LINK.sub(css, page)
    return _SCRIPT.sub(script, page)
