"""Every plotly figure Redline draws, as plain figure dicts (``Plotly.newPlot`` input): the trend
charts of the browser UI, and the revision-evolution and raw-sample plots of `redline compare`'s
report (the paper's analysis-tool plots).

Plotly renders a subset of HTML in every title, tick label, legend and hover text (``<a href>``
becomes a live link), so every name that came from outside goes through `plot_text`.
"""

from __future__ import annotations

import html
from typing import Any

import numpy as np
from redline.detect.compare import RecordedSeries, SeriesVerdict
from redline.recording import SeriesKey
from redline.server.schemas.results import ChangeOut, SeriesOut

SIDE_COLORS = {"baseline": "#1f77b4", "candidate": "#d62728"}
FLAG_COLOR = "#d62728"
LINE_COLOR = "#1f77b4"


def plot_text(text: str) -> str:
    """``text`` shown as itself by plotly: its markup escaped (plotly decodes the entities)."""
    return html.escape(text, quote=False)


def _effect_text(effect: float | None) -> str:
    return "n/a" if effect is None else f"{effect:+.1%}"


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
