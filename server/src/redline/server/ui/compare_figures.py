"""The figures of comparisons: the revision-evolution and raw-sample plots of `redline compare`'s
report (the paper's analysis-tool plots), and the compare page's change of each series' mean."""

from __future__ import annotations

from typing import Any

import numpy as np
from redline.detect.comparison import RecordedSeries, SeriesVerdict
from redline.recording import SeriesKey
from redline.server.schemas.results import Comparison
from redline.server.ui.figures import FLAG_COLOR, SIDE_COLORS, plot_text


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
