"""Plotly figures as plain figure dicts (``Plotly.newPlot`` input): what every figure shares (the
colours, `plot_text`) and the trend charts of the browser UI (`trend_charts`). The comparisons'
figures are in `compare_figures`, the revision's evidence (why flagged, an execution's counters)
in `detail_figures`, the resource models' in `model_figures`.

Plotly renders a subset of HTML in every title, tick label, legend and hover text (``<a href>``
becomes a live link), so every name that came from outside goes through `plot_text`.
"""

from __future__ import annotations

import html
import json
from collections import defaultdict
from itertools import cycle
from typing import TYPE_CHECKING, Any

import numpy as np
from redline.recording import params_name
from redline.server.schemas.results import ChangeOut, SeriesOut
from redline.server.services.trend_view import ChartKey, chart_key, chart_place

if TYPE_CHECKING:
    from redline.server.services.dashboard import TrendData, TrendSeries
    from redline.server.services.trend_view import TrendView

SIDE_COLORS = {"baseline": "#1f77b4", "candidate": "#d62728"}
FLAG_COLOR = "#d62728"
LINE_COLOR = "#1f77b4"


def plot_text(text: str) -> str:
    """``text`` shown as itself by plotly: its markup escaped (plotly decodes the entities)."""
    return html.escape(text, quote=False)


def _effect_text(effect: float | None) -> str:
    return "n/a" if effect is None else f"{effect:+.1%}"


#: one colour per parameter set of a chart (plotly's own ten)
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf",
           "#bcbd22", "#7f7f7f", "#d62728")  # fmt: skip
#: how a change in a regression is marked, by the regression's confirmation
MARKS: dict[str, dict[str, Any]] = {
    "confirmed": {"color": FLAG_COLOR, "symbol": "diamond", "size": 13},
    "suspected": {"color": "#ff7f0e", "symbol": "diamond-open", "size": 13},
    "not_confirmed": {"color": "#7f7f7f", "symbol": "x-thin-open", "size": 11},
    "flagged": {"color": "#9467bd", "symbol": "circle-open", "size": 11},  # no regression
}
LEGEND = {"flagged": "flagged, no alarm", "not_confirmed": "not confirmed"}
MEDIAN_WINDOW = 5


def _rgba(colour: str, alpha: float) -> str:
    red, green, blue = (int(colour[i : i + 2], 16) for i in (1, 3, 5))
    return f"rgba({red},{green},{blue},{alpha})"


def moving_median(values: list[float | None], window: int = MEDIAN_WINDOW) -> list[float | None]:
    """The median of the last ``window`` values present, at each point that has a value."""
    seen: list[float] = []
    out: list[float | None] = []
    for value in values:
        if value is None:
            out.append(None)
            continue
        seen.append(value)
        out.append(float(np.median(seen[-window:])))
    return out


def plot_number(value: float) -> float | None:
    """A value as a chart needs it: five significant digits; None when not finite."""
    return float(f"{value:.5g}") if np.isfinite(value) else None


def _series_traces(
    series: TrendSeries, index: dict[int, int], size: int, colour: str, view: TrendView
) -> list[dict[str, Any]]:
    """Mean per revision with a ±std band, and the moving median when asked. The traces have
    no ``x``: it is every revision of the page, in order, which the page adds once for all."""
    means: list[float | None] = [None] * size
    custom: list[list[float | None] | None] = [None] * size
    for revision_id, pool in series.points.items():
        at = index[revision_id]
        means[at] = plot_number(pool.mean)
        custom[at] = [plot_number(pool.std) or 0.0, pool.n]
    pairs = zip(means, custom, strict=True)
    spread = [(m, c[0] or 0.0) if m is not None and c else None for m, c in pairs]
    upper = [plot_number(s[0] + s[1]) if s else None for s in spread]
    lower = [plot_number(s[0] - s[1]) if s else None for s in spread]
    name = plot_text(params_name(series.ref.params))
    band = {"mode": "lines", "line": {"width": 0}, "hoverinfo": "skip", "showlegend": False}
    traces: list[dict[str, Any]] = [
        {"type": "scatter", "name": f"{name}: mean + std", "y": upper, "legendgroup": name, **band},
        {
            "type": "scatter",
            "name": f"{name}: mean - std",
            "y": lower,
            "legendgroup": name,
            "fill": "tonexty",
            "fillcolor": _rgba(colour, 0.15),
            **band,
        },
        {
            "type": "scatter",
            "mode": "lines+markers",
            "name": name,
            "legendgroup": name,
            "y": means,
            "customdata": custom,
            "hovertemplate": "%{x}<br>" + name + ": %{y:.4g} ± %{customdata[0]:.3g} "
            "(%{customdata[1]} samples)<extra></extra>",
            "line": {"color": colour, "width": 1.5},
            "marker": {"size": 4},
        },
    ]
    if view.median:
        traces.append(
            {
                "type": "scatter",
                "mode": "lines",
                "name": f"{name}: moving median of {MEDIAN_WINDOW}",
                "legendgroup": name,
                "y": moving_median(means),
                "connectgaps": True,
                "hoverinfo": "skip",
                "line": {"color": colour, "width": 2.5, "dash": "dot"},
            }
        )
    return traces


def _mark_traces(
    members: list[TrendSeries], index: dict[int, int], titles: list[str]
) -> list[dict[str, Any]]:
    """The changes in regressions, one trace per confirmation state; a mark's customdata is its
    regression's id (the page opens the regression on a click)."""
    by_state: dict[str, list[tuple[str, float | None, int | None, str]]] = defaultdict(list)
    for series in members:
        name = params_name(series.ref.params)
        for revision_id, mark in series.marks.items():
            pool = series.points.get(revision_id)
            if pool is None:
                continue
            hover = (
                f"{titles[index[revision_id]]}: {plot_text(name)} flagged by {mark.method} "
                f"({_effect_text(mark.effect)})<br>"
                + (
                    f"regression #{mark.regression_id}, {mark.confirmation.replace('_', ' ')}: "
                    "click to open"
                    if mark.regression_id is not None
                    else "not a method that alarms: no regression"
                )
            )
            by_state[mark.confirmation].append(
                (titles[index[revision_id]], plot_number(pool.mean), mark.regression_id, hover)
            )
    traces: list[dict[str, Any]] = []
    for state, style in MARKS.items():
        marks = by_state.get(state)
        if not marks:
            continue
        traces.append(
            {
                "type": "scatter",
                "mode": "markers",
                "name": f"change ({LEGEND.get(state, state.replace('_', ' '))})",
                "x": [m[0] for m in marks],
                "y": [m[1] for m in marks],
                "customdata": [m[2] for m in marks],
                "text": [m[3] for m in marks],
                "hovertemplate": "%{text}<extra></extra>",
                "marker": {**style, "line": {"color": "#000", "width": 1}},
            }
        )
    return traces


def trend_charts(data: TrendData, view: TrendView) -> list[dict[str, Any]]:
    """One chart per case, phase, process and counter, a line per parameter set, in the order
    the page groups them (`chart_place`): a list of
    ``{"id", "key", "case", "phase", "title", "figure"}``; a series trace's x is left out, for
    the page to fill with the x axis's ``categoryarray`` (the revisions' titles as plot text)."""
    titles = [plot_text(revision.title) for revision in data.revisions]
    index = {revision.id: at for at, revision in enumerate(data.revisions)}
    groups: dict[ChartKey, list[TrendSeries]] = defaultdict(list)
    for series in data.series:
        groups[chart_key(series.ref)].append(series)
    order = sorted(groups, key=chart_place)
    charts = []
    for number, key in enumerate(order, start=1):
        case, phase, process, counter = key
        members = sorted(groups[key], key=lambda s: params_name(s.ref.params))
        traces: list[dict[str, Any]] = []
        for colour, series in zip(cycle(PALETTE), members, strict=False):
            traces += _series_traces(series, index, len(titles), colour, view)
        traces += _mark_traces(members, index, titles)
        title = plot_text(f"{case}/{phase} {process}.{counter}")
        layout = {
            "title": {"text": title, "font": {"size": 14}},
            "height": 300,
            "margin": {"l": 60, "r": 20, "t": 40, "b": 60},
            "xaxis": {
                "type": "category",
                "categoryorder": "array",
                "categoryarray": titles,
                "title": {"text": "revision"},
                "automargin": True,
            },
            "yaxis": {"title": {"text": plot_text(counter)}, "type": "log" if view.log else "-"},
            "showlegend": True,
            "legend": {"orientation": "h", "y": -0.35},
            "hovermode": "closest",
        }
        charts.append(
            {
                "id": f"chart-{number}",
                # what the page matches a chart by when it loads a longer history: unambiguous,
                # where the title is not (case "a/b", phase "c" and case "a", phase "b/c")
                "key": json.dumps([case, phase, process, counter]),
                "case": case,
                "phase": phase,
                "title": f"{case}/{phase} {process}.{counter}",
                "figure": {"data": traces, "layout": layout},
            }
        )
    return charts


def trend_figure(series: SeriesOut, changes: list[ChangeOut]) -> dict[str, Any]:
    """Mean per revision (sort-key order) with std error bars; flagged revisions in red."""
    flagged = {
        change.revision: change
        for change in changes
        if change.series.id == series.id and change.flagged
    }
    titles = [plot_text(point.revision) for point in series.points]
    hover = [
        f"{plot_text(p.revision)}<br>mean {p.mean:.4g} ± {p.std:.3g} (n={p.n})"
        for p in series.points
    ]
    trend = {
        "type": "scatter",
        "mode": "lines+markers",
        "name": "mean",
        "x": titles,
        "y": [point.mean for point in series.points],
        "error_y": {
            "type": "data",
            "array": [point.std for point in series.points],
            "visible": True,
        },
        "text": hover,
        "hoverinfo": "text",
        "line": {"color": LINE_COLOR},
    }
    marks = [p for p in series.points if p.revision in flagged]
    regressions = {
        "type": "scatter",
        "mode": "markers",
        "name": "change (KS)",
        "x": [plot_text(p.revision) for p in marks],
        "y": [p.mean for p in marks],
        "text": [
            f"{plot_text(p.revision)}: change flagged<br>mean {p.mean:.4g}, effect "
            f"{_effect_text(flagged[p.revision].effect)} vs "
            f"{plot_text(flagged[p.revision].baseline)}"
            for p in marks
        ],
        "hoverinfo": "text",
        "marker": {
            "color": FLAG_COLOR,
            "size": 14,
            "symbol": "diamond",
            "line": {"color": "#000", "width": 1},
        },
    }
    layout = {
        "title": {"text": plot_text(series.label)},
        "height": 320,
        "margin": {"l": 60, "r": 20, "t": 50},
        "xaxis": {
            "type": "category",
            "categoryorder": "array",
            "categoryarray": titles,
            "title": {"text": "revision"},
        },
        "yaxis": {"title": {"text": plot_text(series.counter)}},
        "showlegend": bool(marks),
    }
    return {"data": [trend, regressions], "layout": layout}
