"""Every plotly figure Redline draws, as plain figure dicts (``Plotly.newPlot`` input): the trend
charts of the browser UI (`trend_charts`), and the revision-evolution and raw-sample plots of
`redline compare`'s report (the paper's analysis-tool plots).

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
from redline.detect.compare import RecordedSeries, SeriesVerdict
from redline.recording import SeriesKey, params_name
from redline.recording.format import HOST_PROCESS
from redline.server.schemas.results import ChangeOut, Comparison, SeriesOut

if TYPE_CHECKING:
    from redline.server.services.dashboard import TrendData, TrendSeries, TrendView
    from redline.server.services.execution_view import ExecutionView
    from redline.server.services.why import WhyFlagged

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


def _short(value: float) -> float | None:
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
        means[at] = _short(pool.mean)
        custom[at] = [_short(pool.std) or 0.0, pool.n]
    pairs = zip(means, custom, strict=True)
    spread = [(m, c[0] or 0.0) if m is not None and c else None for m, c in pairs]
    upper = [_short(s[0] + s[1]) if s else None for s in spread]
    lower = [_short(s[0] - s[1]) if s else None for s in spread]
    name = plot_text(params_name(series.ref.params))
    band = {"mode": "lines", "line": {"width": 0}, "hoverinfo": "skip", "showlegend": False}
    traces: list[dict[str, Any]] = [
        {"type": "scatter", "y": upper, "legendgroup": name, **band},
        {
            "type": "scatter",
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
                (titles[index[revision_id]], _short(pool.mean), mark.regression_id, hover)
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
    the page groups them (case, then phase; the machine's context last): a list of
    ``{"id", "key", "case", "phase", "title", "figure"}``; a series trace's x is left out, for
    the page to fill with the x axis's ``categoryarray`` (the revisions' titles as plot text)."""
    titles = [plot_text(revision.title) for revision in data.revisions]
    index = {revision.id: at for at, revision in enumerate(data.revisions)}
    groups: dict[tuple[str, str, str, str], list[TrendSeries]] = defaultdict(list)
    for series in data.series:
        ref = series.ref
        groups[(ref.case, ref.phase, ref.process, ref.counter)].append(series)
    order = sorted(groups, key=lambda k: (k[0], k[1], k[2] == HOST_PROCESS, k[2], k[3]))
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


def evolution_figure(
    key: SeriesKey, files: list[tuple[str, RecordedSeries]], verdict: SeriesVerdict
) -> dict[str, Any]:
    """Mean ± std of the series in each recording, one trace per side."""
    data = []
    for side, color in SIDE_COLORS.items():
        labels, means, stds = [], [], []
        for file_side, recorded in files:
            values = [value for _, value in recorded.timeline.get(key, [])]
            if file_side == side and values:
                labels.append(plot_text(recorded.label))
                means.append(float(np.mean(values)))
                stds.append(float(np.std(values)))
        data.append(
            {
                "type": "scatter",
                "mode": "markers+lines",
                "name": side,
                "x": labels,
                "y": means,
                "error_y": {"type": "data", "array": stds, "visible": True},
                "marker": {"color": color},
            }
        )
    flag = "changed: " if verdict.result.flagged else ""
    title = (
        f"{flag}{plot_text(f'{key.process}.{key.counter}')} (D {verdict.result.score:.3f}, "
        f"effect {verdict.result.effect:+.1%})"
    )
    layout = {
        "title": {"text": title, "font": {"size": 13}},
        "height": 300,
        "margin": {"l": 60, "r": 20, "t": 40, "b": 80},
        "xaxis": {"type": "category", "title": {"text": "recording (revision)"}},
        "yaxis": {"title": {"text": plot_text(key.counter)}},
    }
    return {"data": data, "layout": layout}


def timeseries_figure(key: SeriesKey, files: list[tuple[str, RecordedSeries]]) -> dict[str, Any]:
    """The raw samples of one series in each recording, against seconds since it began."""
    data = []
    for side, recorded in files:
        points = recorded.timeline.get(key, [])
        if not points:
            continue
        start = points[0][0]
        data.append(
            {
                "type": "scatter",
                "mode": "lines",
                "name": f"{side}: {plot_text(recorded.label)}",
                "x": [(t - start) / 1e9 for t, _ in points],
                "y": [v for _, v in points],
                "line": {"color": SIDE_COLORS[side], "width": 1},
            }
        )
    layout = {
        "title": {
            "text": f"{plot_text(f'{key.process}.{key.counter}')}: raw samples",
            "font": {"size": 13},
        },
        "height": 300,
        "margin": {"l": 60, "r": 20, "t": 40, "b": 40},
        "xaxis": {"title": {"text": "seconds into the segment"}},
        "yaxis": {"title": {"text": plot_text(key.counter)}},
    }
    return {"data": data, "layout": layout}


def _ecdf(sketches: list[list[float]]) -> tuple[np.ndarray, np.ndarray]:
    """The pooled ECDF of executions' quantile sketches (each quantile one equal step)."""
    values = np.sort(np.concatenate([np.asarray(s, dtype=float) for s in sketches if s]))
    return values, (np.arange(values.size) + 1) / max(1, values.size)


def why_figures(why: WhyFlagged) -> list[dict[str, Any]]:
    """The "why flagged" page's charts: the executions' values against the baseline's level and
    the effect floors; the two sides' distributions with the largest gap between them marked."""
    found = why.detection
    title = plot_text(found.series.label)
    base = [v.median for v in why.baseline]
    level = float(np.median(base)) if base else float("nan")
    least = max(abs(level) * float(why.thresholds.get("min_effect", 0.0)), why.floor)
    points = [
        {
            "type": "scatter",
            "mode": "markers",
            "name": name,
            "x": [plot_text(v.revision) for v in values],
            "y": [v.median for v in values],
            "customdata": [[v.mean, v.n] for v in values],
            "hovertemplate": "%{x}: median %{y:.4g} (mean %{customdata[0]:.4g}, "
            "%{customdata[1]} samples)<extra>" + name + "</extra>",
            "marker": {"color": SIDE_COLORS[side], "size": 10 if side == "candidate" else 7},
        }
        for side, name, values in (
            ("baseline", "baseline executions", why.baseline),
            ("candidate", "candidate executions", why.candidate),
        )
    ]
    order = [plot_text(t) for t in [*why.baseline_titles, found.revision]]
    shapes = []
    if np.isfinite(level):
        shapes = [
            {"type": "line", "xref": "paper", "x0": 0, "x1": 1, "y0": y, "y1": y,
             "line": {"color": color, "dash": dash, "width": 1.5}}
            for y, color, dash in (
                (level, SIDE_COLORS["baseline"], "solid"),
                (level + least, "#999", "dot"),
                (level - least, "#999", "dot"),
            )
        ]  # fmt: skip
    levels = {
        "data": points,
        "layout": {
            "title": {"text": f"{title}: each execution's median", "font": {"size": 14}},
            "height": 340,
            "margin": {"l": 70, "r": 20, "t": 50, "b": 60},
            "xaxis": {"type": "category", "categoryorder": "array", "categoryarray": order},
            "yaxis": {"title": {"text": plot_text(found.series.counter)}},
            "shapes": shapes,
            "annotations": [
                {
                    "xref": "paper", "yref": "y", "x": 1, "y": level + least, "xanchor": "right",
                    "text": "smallest change worth reporting", "showarrow": False,
                    "font": {"size": 11, "color": "#666"},
                }
            ] if np.isfinite(level) else [],
        },
    }  # fmt: skip
    sides = {
        side: _ecdf([v.sketch for v in values])
        for side, values in (("baseline", why.baseline), ("candidate", why.candidate))
    }
    traces = [
        {
            "type": "scatter",
            "mode": "lines",
            "line": {"shape": "hv", "color": SIDE_COLORS[side]},
            "name": f"{side} ({len(values)} quantiles)",
            "x": values.tolist(),
            "y": steps.tolist(),
        }
        for side, (values, steps) in sides.items()
        if values.size
    ]
    gap_shapes, gap_text = [], ""
    if all(values.size for values, _ in sides.values()):
        grid = np.union1d(sides["baseline"][0], sides["candidate"][0])
        base_values, cand_values = sides["baseline"][0], sides["candidate"][0]
        at_base = np.searchsorted(base_values, grid, side="right") / base_values.size
        at_cand = np.searchsorted(cand_values, grid, side="right") / cand_values.size
        widest = int(np.argmax(np.abs(at_base - at_cand)))
        gap = float(abs(at_base[widest] - at_cand[widest]))
        x = float(grid[widest])
        gap_shapes = [
            {"type": "line", "x0": x, "x1": x, "y0": float(at_base[widest]),
             "y1": float(at_cand[widest]), "line": {"color": "#000", "width": 3}}
        ]  # fmt: skip
        gap_text = f" (largest gap {gap:.2f} at {x:.4g}: KS's D on these quantiles)"
    distributions = {
        "data": traces,
        "layout": {
            "title": {
                "text": f"{title}: the two sides' distributions{gap_text}",
                "font": {"size": 14},
            },
            "height": 340,
            "margin": {"l": 70, "r": 20, "t": 50, "b": 60},
            "xaxis": {"title": {"text": plot_text(found.series.counter)}},
            "yaxis": {"title": {"text": "share of samples at or below"}, "range": [0, 1.02]},
            "shapes": gap_shapes,
        },
    }
    return [levels, distributions]


SEGMENT_COLORS = ("rgba(31,119,180,0.08)", "rgba(255,127,14,0.08)")


def execution_figures(view: ExecutionView) -> list[dict[str, Any]]:
    """The execution page's charts: each raw counter of the component's processes against time
    with its phases shaded and named (the paper's Figure 5); then each counter's mean against
    each numeric test parameter (its correlation plots), one line per case and phase."""
    shapes, notes = [], []
    for number, segment in enumerate(view.segments):
        begin = (segment.begin_ns - view.start_ns) / 1e9
        end = (segment.end_ns - view.start_ns) / 1e9
        shapes.append(
            {"type": "rect", "xref": "x", "yref": "paper", "x0": begin, "x1": end, "y0": 0,
             "y1": 1, "fillcolor": SEGMENT_COLORS[number % 2], "line": {"width": 0},
             "layer": "below"}
        )  # fmt: skip
        name = f"{segment.case}/{segment.phase} [{params_name(segment.params)}]"
        notes.append(
            {"xref": "x", "yref": "paper", "x": (begin + end) / 2, "y": 1, "yanchor": "bottom",
             "text": plot_text(name) + (" (warm-up)" if segment.warmup else ""),
             "showarrow": False, "textangle": -30, "font": {"size": 9, "color": "#555"}}
        )  # fmt: skip
    charts = [
        {
            "data": [
                {
                    "type": "scatter",
                    "mode": "lines",
                    "name": plot_text(f"{process}.{counter}"),
                    "x": [t for t, _ in points],
                    "y": [_short(v) for _, v in points],
                    "line": {"width": 1},
                }
            ],
            "layout": {
                "title": {"text": plot_text(f"{process}.{counter}"), "font": {"size": 14}},
                "height": 300,
                "margin": {"l": 70, "r": 20, "t": 90, "b": 50},
                "xaxis": {"title": {"text": "seconds into the run"}},
                "yaxis": {"title": {"text": plot_text(counter)}},
                "shapes": shapes,
                "annotations": notes,
            },
        }
        for (process, counter), points in view.timelines.items()
    ]
    against: dict[tuple[str, str, str], dict[tuple[str, str], list[tuple[float, float]]]] = (
        defaultdict(lambda: defaultdict(list))
    )
    for row in view.summaries:
        if row.kind not in ("counter", "driver"):
            continue
        for name, value in row.params.items():
            if isinstance(value, int | float) and not isinstance(value, bool):
                line = against[(name, row.process, row.counter)][(row.case, row.phase)]
                line.append((float(value), row.mean))
    for (param, process, counter), lines in sorted(against.items()):
        if not any(len({x for x, _ in points}) > 1 for points in lines.values()):
            continue  # one value of the parameter: nothing to correlate
        charts.append(
            {
                "data": [
                    {
                        "type": "scatter",
                        "mode": "markers+lines",
                        "name": plot_text(f"{case}/{phase}"),
                        "x": [x for x, _ in sorted(points)],
                        "y": [_short(y) for _, y in sorted(points)],
                    }
                    for (case, phase), points in sorted(lines.items())
                ],
                "layout": {
                    "title": {
                        "text": plot_text(f"{process}.{counter} against {param}"),
                        "font": {"size": 14},
                    },
                    "height": 300,
                    "margin": {"l": 70, "r": 20, "t": 50, "b": 50},
                    "xaxis": {"title": {"text": plot_text(param)}},
                    "yaxis": {"title": {"text": f"mean {plot_text(counter)}"}},
                },
            }
        )
    return charts


def comparison_figure(comparison: Comparison) -> dict[str, Any]:
    """The relative change of each judged series' mean from one revision to the other, worst
    first (a change for the worse in red, for the better in green)."""
    rows = [s for s in comparison.series if s.series.judged and s.change is not None]
    rows.sort(key=lambda s: -(s.change or 0.0) * (1 if s.series.worse == "increase" else -1))
    worse = [(s.change or 0.0) * (1 if s.series.worse == "increase" else -1) > 0 for s in rows]
    return {
        "data": [
            {
                "type": "bar",
                "orientation": "h",
                "y": [plot_text(s.series.label) for s in rows],
                "x": [round(100 * (s.change or 0.0), 2) for s in rows],
                "marker": {"color": [FLAG_COLOR if w else "#2ca02c" for w in worse]},
                "hovertemplate": "%{y}: %{x:+.1f} %<extra></extra>",
            }
        ],
        "layout": {
            "title": {
                "text": plot_text(f"{comparison.candidate} against {comparison.base}")
                + ": change of the mean",
                "font": {"size": 14},
            },
            "height": max(300, 22 * len(rows) + 100),
            "margin": {"l": 420, "r": 20, "t": 50, "b": 50},
            "xaxis": {"title": {"text": "change of the mean, %"}},
            "yaxis": {"autorange": "reversed", "automargin": True},
        },
    }
