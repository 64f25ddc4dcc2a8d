"""Plotly trend figures for the browser UI, as plain figure dicts (``Plotly.newPlot`` input)."""

from __future__ import annotations

from typing import Any

from redline.server.schemas import ChangeOut, SeriesOut

FLAG_COLOR = "#d62728"
LINE_COLOR = "#1f77b4"


def _effect_text(effect: float | None) -> str:
    return "n/a" if effect is None else f"{effect:+.1%}"


def trend_figure(series: SeriesOut, changes: list[ChangeOut]) -> dict[str, Any]:
    """Mean per revision (sort-key order) with std error bars; flagged revisions in red."""
    flagged = {
        change.revision: change
        for change in changes
        if change.series.id == series.id and change.flagged
    }
    titles = [point.revision for point in series.points]
    hover = [f"{p.revision}<br>mean {p.mean:.4g} ± {p.std:.3g} (n={p.n})" for p in series.points]
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
        "x": [p.revision for p in marks],
        "y": [p.mean for p in marks],
        "text": [
            f"{p.revision}: change flagged<br>mean {p.mean:.4g}, effect "
            f"{_effect_text(flagged[p.revision].effect)} vs "
            f"{flagged[p.revision].baseline}"
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
        "title": {"text": series.label},
        "height": 320,
        "margin": {"l": 60, "r": 20, "t": 50},
        "xaxis": {
            "type": "category",
            "categoryorder": "array",
            "categoryarray": titles,
            "title": {"text": "revision"},
        },
        "yaxis": {"title": {"text": series.counter}},
        "showlegend": bool(marks),
    }
    return {"data": [trend, regressions], "layout": layout}
