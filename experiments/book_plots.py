"""The book's error-vs-cost data and figures: each approximation of a family aggregated over its cases
(:class:`FamilyPoint`, :func:`family_points`), its error made comparable across families
(:func:`normalised_error`), and the figures the book draws from them into ``OUT/book-figures/``: the
cross-family summary (:func:`summary_plot`) and one Pareto plot per family (:func:`draw_book_figures`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from .figures import pareto_plot, pyplot, save_figure
from .records import Approximation, Results
from .report_doc import METRICS, headline_metric

__all__ = [
    "BOOK_FIGURES",
    "PRECOMPUTE_PLOT_NOTE",
    "FamilyPoint",
    "draw_book_figures",
    "family_points",
    "is_plotted",
    "normalised_error",
    "pareto_point",
    "summary_plot",
]

BOOK_FIGURES = "book-figures"
"""The folder (beside ``book.tex``) of the figures the book draws itself."""


# ------------------------------------------------------------------------------ normalised error
def normalised_error(ap: Approximation) -> tuple[float, float | None, bool | None, str] | None:
    """The error of one approximation in one case made comparable across families, as
    ``(value, noise floor, resolved, kind)``, or None where the case holds no such metric.

    ``kind`` ``"peak"``: the RMSE relative to the peak of the reference over the compared pixels,
    ``RMSE / peak = 10^(−PSNR/20)``, read from the PSNR that rtfit measures beside the RMSE
    (``PSNR = 10·log10(peak² / mean d²)``, ``rtfit.fitting.metrics``); its floor is
    ``10^(−ceiling/20)`` with the PSNR's noise ceiling, and it is resolved exactly when the PSNR is
    (the same test as the RMSE's). ``kind`` ``"rms"``: a family without PSNR that reports ``rel_rmse``
    = RMSE / RMS of the reference (irradiance-bases) gives that; since RMS ≤ peak it is an upper bound
    of RMSE / peak. Both are dimensionless, so one light's irradiance error and a sky's radiance error
    sit on one axis.
    """
    m = ap.metrics.get("psnr")
    if m is not None and m.value is not None:
        floor = None if m.noise_floor is None else 10.0 ** (-m.noise_floor / 20.0)
        return 10.0 ** (-m.value / 20.0), floor, m.resolved, "peak"
    m = ap.metrics.get("rel_rmse")
    if m is not None and m.value is not None:
        return m.value, m.noise_floor, m.resolved, "rms"
    return None


@dataclass(frozen=True)
class FamilyPoint:
    """One approximation of one family over the cases it was evaluated in.

    ``error``/``floor``: means over those cases of the family's headline metric ``metric`` and its
    noise floor; ``resolved``: in how many of the ``cases`` the error is resolved (above the noise);
    ``ns_per_pixel``: mean measured cost (None: not timed); ``norm``/``norm_floor``/``norm_kind``/
    ``norm_resolved``: the same for :func:`normalised_error` (None where the family has none)."""

    experiment: str
    method: str
    label: str
    metric: str
    cases: int
    error: float | None
    floor: float | None
    resolved: int
    ns_per_pixel: float | None
    norm: float | None
    norm_floor: float | None
    norm_kind: str | None
    norm_resolved: int
    precompute_ns: float | None = None
    """Its precompute's share per pixel if paid every frame (`records.PixelCost.precompute_per_pixel`, mean
    over the cases; None: no precompute timed)."""
    precompute_trigger: str | None = None


def _mean(xs: list[float]) -> float | None:
    return sum(xs) / len(xs) if xs else None


def family_points(r: Results) -> list[FamilyPoint]:
    """Every approximation of ``r`` aggregated over its cases (see :class:`FamilyPoint`), in order of
    first appearance. Cost: the approximation's own measured cost, else the ``costs`` row under its id."""
    head = headline_metric(r.cases)
    order: dict[str, list[Approximation]] = {}
    for c in r.cases:
        for ap in c.approximations:
            order.setdefault(ap.method, []).append(ap)
    cost_rows = {c.method: c.ns_per_pixel for c in r.costs}
    out = []
    for method, aps in order.items():
        errs, floors, resolved, ns = [], [], 0, []
        timed = [ap.cost for ap in aps if ap.cost and ap.cost.precompute_per_pixel]
        pre = [c.precompute_per_pixel for c in timed if c.precompute_per_pixel]
        trig = timed[0].precompute_trigger if timed else None
        norms, nfloors, nres, kinds = [], [], 0, set()
        for ap in aps:
            m = ap.metrics.get(head) if head else None
            if m is not None and m.value is not None:
                errs.append(m.value)
                resolved += m.resolved is not False
                if m.noise_floor is not None:
                    floors.append(m.noise_floor)
            if ap.cost is not None and ap.cost.ns_per_pixel is not None:
                ns.append(ap.cost.ns_per_pixel)
            ne = normalised_error(ap)
            if ne is not None:
                norms.append(ne[0])
                if ne[1] is not None:
                    nfloors.append(ne[1])
                nres += ne[2] is not False
                kinds.add(ne[3])
        out.append(
            FamilyPoint(
                experiment=r.experiment,
                method=method,
                label=next((ap.display for ap in aps if ap.label), method),
                metric=head or "",
                cases=len(aps),
                error=_mean(errs),
                floor=_mean(floors) if len(floors) == len(errs) else None,
                resolved=resolved,
                ns_per_pixel=_mean(ns) if ns else cost_rows.get(method),
                norm=_mean(norms) if len(norms) == len(aps) else None,
                norm_floor=_mean(nfloors) if norms and len(nfloors) == len(norms) else None,
                norm_kind=kinds.pop() if len(kinds) == 1 and len(norms) == len(aps) else None,
                norm_resolved=nres,
                precompute_ns=_mean(pre),
                precompute_trigger=trig,
            )
        )
    return out


# ---------------------------------------------------------------------------------------- figures
_FAMILY_STYLE = ("o", "s", "^", "D", "v", "P", "X", "<", ">", "h")


def summary_plot(path, families: Sequence[tuple[str, list[FamilyPoint]]]) -> Path:
    """The cross-family figure: normalised error (log) against ns/pixel (log), one colour and marker
    per family, each point numbered as in the summary table; open markers: not resolved in any case."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    colours = [plt.get_cmap("tab10")(i) for i in range(10)]
    k = 0
    for f, (name, pts) in enumerate(families):
        colour, marker = colours[f % len(colours)], _FAMILY_STYLE[f % len(_FAMILY_STYLE)]
        shown = False
        for p in pts:
            if not is_plotted(p):
                continue
            k += 1
            assert p.norm is not None and p.ns_per_pixel is not None
            filled = p.norm_resolved > 0
            ax.scatter(
                [p.ns_per_pixel],
                [p.norm],
                s=30,
                marker=marker,
                facecolors=colour if filled else "none",
                edgecolors=colour,
                label=None if shown else name + (" (RMSE/RMS*)" if p.norm_kind == "rms" else ""),
                zorder=3,
            )
            shown = True
            ax.annotate(
                str(k), (p.ns_per_pixel, p.norm), textcoords="offset points", xytext=(3, 3), fontsize=6
            )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("cost (ns per pixel, measured on the run's device)")
    ax.set_ylabel("normalised error: RMSE / reference peak")
    ax.grid(alpha=0.3, which="both", lw=0.5)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    return save_figure(fig, path)


PRECOMPUTE_PLOT_NOTE = (
    " A method with a precompute (a bake an engine pays apart from its per-pixel kernel) is drawn twice: "
    "its kernel alone, and (open marker, joined) its kernel plus the precompute spread over the case's "
    "pixels as if paid every frame (an upper bound where it is paid per light or scene change); the "
    "Pareto front is over the kernels alone."
)
"""The error-vs-cost caption's words on precomputes (`figures.pareto_plot`'s ``x_pre``)."""


def pareto_point(p: FamilyPoint) -> dict:
    """A `pareto_plot` point: cost, error, id; ``x_pre``: the cost with the precompute paid every frame."""
    point = {"x": p.ns_per_pixel, "y": p.error, "label": p.method}
    if p.precompute_ns and p.ns_per_pixel:
        point["x_pre"] = p.ns_per_pixel + p.precompute_ns
    return point


def is_plotted(p: FamilyPoint) -> bool:
    """Whether ``p`` is on the summary plot: a positive normalised error and a positive measured cost."""
    return p.norm is not None and p.norm > 0 and p.ns_per_pixel is not None and p.ns_per_pixel > 0


def _pareto_points(pts: list[FamilyPoint]) -> list[FamilyPoint]:
    """The points of a family's Pareto plot: a positive error and a positive measured cost."""
    return [p for p in pts if p.error is not None and p.error > 0 and p.ns_per_pixel and p.ns_per_pixel > 0]


def draw_book_figures(out_dir: Path, entries: list[tuple[str, Results]]) -> tuple[dict[str, str], list[Path]]:
    """Draw the book's figures under ``out_dir/BOOK_FIGURES``: the summary where any point is plotted, and a
    Pareto plot per family of two points or more. Returns ``({key: relative path}, written paths)`` with the
    keys :func:`.book.render_book` reads (``"summary"``, ``"pareto:EXPERIMENT"``)."""
    figs: dict[str, str] = {}
    written: list[Path] = []
    fam_points = [(r.experiment, family_points(r)) for _, r in entries]
    if any(is_plotted(p) for _, pts in fam_points for p in pts):
        rel = f"{BOOK_FIGURES}/summary.pdf"
        written.append(summary_plot(out_dir / rel, fam_points))
        figs["summary"] = rel
    for name, pts in fam_points:
        pp = _pareto_points(pts)
        if len(pp) < 2:
            continue
        head = pp[0].metric
        floors = [p.floor for p in pp if p.floor is not None]
        rel = f"{BOOK_FIGURES}/pareto-{name}.pdf"
        written.append(
            pareto_plot(
                out_dir / rel,
                [pareto_point(p) for p in pp],
                "cost (ns per pixel)",
                f"mean {METRICS.get(head, (head,))[0]} over cases",
                title=name,
                floor=sum(floors) / len(floors) if floors else None,
            )
        )
        figs[f"pareto:{name}"] = rel
    return figs, written
