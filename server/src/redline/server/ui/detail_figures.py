"""The figures of a revision's evidence: the "why flagged" page's values and distributions, and
an execution's raw counters against time with its phases."""

from __future__ import annotations

from collections import defaultdict
from typing import TYPE_CHECKING, Any

import numpy as np
from redline.recording import params_name
from redline.server.ui.figures import SIDE_COLORS, plot_number, plot_text

if TYPE_CHECKING:
    from redline.server.services.execution_view import ExecutionView
    from redline.server.services.why import WhyFlagged


def _ecdf(sketches: list[list[float]]) -> tuple[np.ndarray, np.ndarray]:
    """The pooled ECDF of executions' quantile sketches (each quantile one equal step)."""
    pooled = [np.asarray(s, dtype=float) for s in sketches if s]
    values = np.sort(np.concatenate(pooled)) if pooled else np.empty(0)  # no baseline: none
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


#: the width of a chart's plotting area (px) and of a label's character (px, at size 9), about
PLOT_PX, CHAR_PX = 900, 5.5


def _fitting(name: str, number: int, share: float) -> str:
    """A phase's label as wide as its shaded band (``share`` of the run): its name when that
    fits, else its number (the name on hover), so that short phases' labels never overlap."""
    return name if len(name) * CHAR_PX <= share * PLOT_PX else f"{number + 1}"


def execution_figures(view: ExecutionView) -> list[dict[str, Any]]:
    """The execution page's charts: each raw counter of the component's processes against time
    with its phases shaded and named (the paper's Figure 5); then each counter's mean against
    each numeric test parameter (its correlation plots), one line per case and phase."""
    shapes, notes = [], []
    ends = [(s.end_ns - view.start_ns) / 1e9 for s in view.segments]
    ends += [points[-1][0] for points in view.timelines.values() if points]
    span = max([*ends, 1e-9])  # the x axis: the run, seconds
    for number, segment in enumerate(view.segments):
        begin = (segment.begin_ns - view.start_ns) / 1e9
        end = (segment.end_ns - view.start_ns) / 1e9
        shapes.append(
            {"type": "rect", "xref": "x", "yref": "paper", "x0": begin, "x1": end, "y0": 0,
             "y1": 1, "fillcolor": SEGMENT_COLORS[number % 2], "line": {"width": 0},
             "layer": "below"}
        )  # fmt: skip
        name = f"{segment.case}/{segment.phase} [{params_name(segment.params)}]"
        name += " (warm-up)" if segment.warmup else ""
        notes.append(
            {"xref": "x", "yref": "paper", "x": (begin + end) / 2, "y": 1, "yanchor": "bottom",
             "text": plot_text(_fitting(name, number, (end - begin) / span)),
             "hovertext": plot_text(name), "showarrow": False,
             "font": {"size": 9, "color": "#555"}}
        )  # fmt: skip
    charts = [
        {
            "data": [
                {
                    "type": "scatter",
                    "mode": "lines",
                    "name": plot_text(f"{process}.{counter}"),
                    "x": [t for t, _ in points],
                    "y": [plot_number(v) for _, v in points],
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
                        "y": [plot_number(y) for _, y in sorted(points)],
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
