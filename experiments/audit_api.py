"""The audit as a notebook reads it: one record per case × row, and the inline summary (issue 37 §1).

`AuditResult.metrics(case, row)` gives each metric as a `MetricValue` (``value``, ``noise_floor``,
``resolved``, ``debiased``); `AuditResult.metric_values` the bare floats. This module builds on them:

* `summary_rows(result)` — one `SummaryRow` per case × row: label, RMSE with its noise floor and resolved
  flag, the fit's flag, the cost per pixel (the numbers the report's first table shows);
* `summary_html(result)` — those rows as an HTML table, with the run's one-sentence findings per case,
  what was skipped and small inline images (each case's reference beside its rows, PNG data URIs written
  by `png_data_uri`): what `AuditResult._repr_html_` shows inline in Jupyter (the interactive viewer stays
  in ``write_report``'s ``viewer.html``: it needs its own files);
* `summary_document(result)` — the JSON document of ``rtfit audit … --json FILE`` (`SUMMARY_FORMAT`);
* `to_dataframe(result)` — the same rows as a ``pandas.DataFrame`` when pandas is installed (rtfit does not
  depend on it: without it, one `ImportError` line saying so).

Each function takes an `rtfit.experiments.audit_run.AuditResult` (not imported here: audit_run imports this
module).
"""

from __future__ import annotations

import base64
import html
import math
import struct
import zlib
from dataclasses import asdict, dataclass

import numpy as np

__all__ = [
    "SUMMARY_FORMAT",
    "THUMBNAIL_MAX_PIXELS",
    "SummaryRow",
    "png_data_uri",
    "summary_document",
    "summary_html",
    "summary_rows",
    "to_dataframe",
]


@dataclass(frozen=True)
class SummaryRow:
    """One method on one case. ``rmse``/``rmse_floor``: the RMSE against the reference and the RMSE the
    reference's own noise alone would give (`rtfit.fitting.compute_metrics`); ``resolved``: the RMSE lies
    above twice that floor, so the error is the method's, not the reference's noise; ``fitted``: the row's
    free parameters were fitted to this scene; ``ns_per_pixel``: its measured cost (None where not
    measured)."""

    case: str
    row: str
    label: str
    units: str
    rmse: float | None
    rmse_floor: float | None
    resolved: bool | None
    fitted: bool
    user: bool
    ns_per_pixel: float | None


def summary_rows(result) -> list[SummaryRow]:
    """Every case × row of ``result`` in the run's order (`SummaryRow`)."""
    units = {c.id: c.units for c in result.cases}
    out = []
    for case, rows in result.outcomes.items():
        for row, o in rows.items():
            m = o.metrics.get("rmse")
            cost = result.costs.get(o.method.id, {}).get("ns_per_pixel")
            out.append(
                SummaryRow(
                    case=case,
                    row=row,
                    label=o.label,
                    units=units.get(case, ""),
                    rmse=None if m is None else float(m.value),
                    rmse_floor=None if m is None else float(m.noise_floor),
                    resolved=None if m is None else bool(m.resolved),
                    fitted=o.fit is not None,
                    user=bool(o.user),
                    ns_per_pixel=None if cost is None else float(cost),
                )
            )
    return out


def _num(x: float | None, fmt: str = ".3g") -> str:
    if x is None:
        return "—"
    return format(x, fmt) if math.isfinite(x) else str(x)


THUMBNAIL_MAX_PIXELS = 256 * 256
"""Largest image (pixels) `summary_html` shows inline; larger audits show the table alone (the report has
the figures)."""


def png_data_uri(rgb: np.ndarray, scale: float) -> str:
    """An (H, W, 3) linear image as an 8-bit sRGB-ish PNG data URI (values / ``scale``, clipped, gamma
    1/2.2): a stdlib PNG writer (zlib), so that a notebook's inline view needs no imaging library."""
    img = np.nan_to_num(np.asarray(rgb, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    img = np.clip(img / scale if scale > 0 else img * 0.0, 0.0, 1.0) ** (1 / 2.2)
    pix = (img * 255.0 + 0.5).astype(np.uint8)
    h, w = pix.shape[:2]
    raw = b"".join(b"\x00" + pix[y].tobytes() for y in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b"")
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def _thumbnails(result) -> str:
    """Per case: the reference and each row's image on one exposure (the reference's 99th percentile)."""
    out = []
    for c in result.cases:
        ref = np.asarray(c.reference.mean)
        rows = result.outcomes.get(c.id, {})
        if ref.ndim != 3 or ref.shape[0] * ref.shape[1] > THUMBNAIL_MAX_PIXELS or not rows:
            continue
        finite = ref[np.isfinite(ref)]
        scale = float(np.percentile(finite, 99)) if finite.size else 1.0
        cells = [("reference", ref)] + [(o.label, o.image) for o in rows.values()]
        figs = "".join(
            f"<figure style='display:inline-block;margin:2px'><img src='{png_data_uri(img, scale)}' "
            f"style='width:96px;image-rendering:pixelated'><figcaption style='font-size:small'>"
            f"{html.escape(label)}</figcaption></figure>"
            for label, img in cells
            if np.asarray(img).shape == ref.shape
        )
        out.append(f"<div><b>{html.escape(c.label)}</b><br>{figs}</div>")
    return "".join(out)


def summary_html(result, images: bool = True) -> str:
    """The inline summary: a table of case × row (RMSE, noise floor, resolved, fitted, cost), the findings
    sentence and the skipped families, then (``images``, for images up to `THUMBNAIL_MAX_PIXELS`) each case's
    reference beside its rows' images on one exposure. Plain HTML (no scripts; images as PNG data URIs), so
    that it renders in Jupyter, VS Code and exported notebooks alike."""
    e = html.escape
    labels = {c.id: c.label for c in result.cases}
    head = (
        "<tr><th>case</th><th>row</th><th>RMSE</th><th>noise floor</th><th>resolved</th>"
        "<th>fitted</th><th>ns / pixel</th></tr>"
    )
    body = []
    for r in summary_rows(result):
        unit = "" if r.units in ("", "1") else f" {r.units}"
        resolved = "—" if r.resolved is None else ("yes" if r.resolved else "no (within the noise)")
        body.append(
            f"<tr><td>{e(labels.get(r.case, r.case))}</td><td>{e(r.label)}{' (user)' if r.user else ''}</td>"
            f"<td>{_num(r.rmse, '.4g')}{e(unit)}</td><td>{_num(r.rmse_floor, '.2g')}</td><td>{resolved}</td>"
            f"<td>{'yes' if r.fitted else ''}</td><td>{_num(r.ns_per_pixel)}</td></tr>"
        )
    summary = getattr(result.results, "summary", "")
    parts = [
        f"<div class='rtfit-audit'><p><b>rtfit audit</b> of {e(result.info.source)}"
        + (f" — <i>{e(result.partial)}</i>" if result.partial else "")
        + "</p>",
        f"<table><thead>{head}</thead><tbody>{''.join(body)}</tbody></table>",
    ]
    if summary:
        parts.append(f"<p>{e(summary)}</p>")
    if result.skipped:
        items = "".join(f"<li>{e(s)}</li>" for s in result.skipped)
        parts.append(
            f"<details><summary>not audited ({len(result.skipped)})</summary><ul>{items}</ul></details>"
        )
    if images:
        thumbs = _thumbnails(result)
        if thumbs:
            parts.append(f"<details open><summary>images</summary>{thumbs}</details>")
    if result.out is not None:
        parts.append(f"<p>report: {e(str(result.out))}/report.html</p>")
    parts.append("</div>")
    return "".join(parts)


def to_dataframe(result):
    """`summary_rows` as a ``pandas.DataFrame`` (one row per case × row); `ImportError` (one line) without
    pandas, which rtfit does not depend on."""
    try:
        import pandas as pd
    except ImportError:
        raise ImportError(
            "to_dataframe needs pandas (pip install pandas); summary_rows gives the same rows without it"
        ) from None
    return pd.DataFrame([asdict(r) for r in summary_rows(result)])


SUMMARY_FORMAT = "rtfit.audit-summary/1"


def _finite(x) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


def _json_safe(obj):
    """Plain JSON with non-finite numbers (an unbounded parameter's ±inf bound) as null."""
    if isinstance(obj, dict):
        return {str(k): _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_json_safe(v) for v in obj]
    if isinstance(obj, bool | str) or obj is None:
        return obj
    try:
        return _finite(float(obj))
    except (TypeError, ValueError):
        return str(obj)


def summary_document(result) -> dict:
    """``rtfit audit … --json FILE``: the run in one JSON document (format `SUMMARY_FORMAT`): the scene,
    the findings sentence, per case its rows with every metric as ``{value, noise_floor, resolved,
    debiased}`` (non-finite numbers as null), the fitted parameters and the cost; the checks, what was not
    audited, the timings and the report's path. results.json (``rtfit.results/1``) holds everything else."""
    cases = []
    for c in result.cases:
        rows = []
        for row, o in result.outcomes.get(c.id, {}).items():
            cost = result.costs.get(o.method.id, {}).get("ns_per_pixel")
            rows.append(
                {
                    "row": row,
                    "label": o.label,
                    "user": bool(o.user),
                    "metrics": o.metrics.to_dict() if hasattr(o.metrics, "to_dict") else {},
                    "fit": None if o.fit is None else _json_safe(o.fit["parameters"]),
                    "ns_per_pixel": _finite(cost),
                }
            )
        cases.append({"id": c.id, "label": c.label, "units": c.units, "rows": rows})
    return {
        "format": SUMMARY_FORMAT,
        "scene": result.info.source,
        "summary": result.results.summary,
        "partial": result.partial,
        "cases": cases,
        "checks": [{"name": k.name, "passed": bool(k.passed)} for k in result.results.checks],
        "skipped": list(result.skipped),
        "timings": {k: _finite(v) for k, v in result.timings.items()},
        "report": None if result.out is None else str((result.out / "report.html").resolve()),
    }
