"""The model page's charts: per target, the measured and the predicted usage over the training
steps (the paper's Figure 8), from the series the worker kept (`ResourceModelRow.plot`)."""

from __future__ import annotations

from typing import Any

from redline.server.ui.figures import plot_text

TITLES = {"cpu_percent": "CPU (% of a core)", "rss_bytes": "RSS (bytes)"}


def model_figures(plot: dict[str, Any]) -> list[dict[str, Any]]:
    steps = list(range(len(plot.get("t", []))))
    charts = []
    for target, title in TITLES.items():
        series = plot.get(target)
        if not series:
            continue
        charts.append(
            {
                "data": [
                    {
                        "type": "scatter",
                        "mode": "lines",
                        "name": "measured",
                        "x": steps,
                        "y": series["measured"],
                        "line": {"width": 1},
                    },
                    {
                        "type": "scatter",
                        "mode": "lines",
                        "name": "predicted",
                        "x": steps,
                        "y": series["predicted"],
                        "line": {"width": 1, "dash": "dot"},
                    },
                ],  # fmt: skip
                "layout": {
                    "title": {"text": plot_text(f"{title}: measured and predicted")},
                    "xaxis": {"title": {"text": "training step (1 s each, segment after segment)"}},
                    "yaxis": {"title": {"text": plot_text(title)}},
                    "height": 320,
                    "margin": {"t": 50, "r": 20, "b": 50, "l": 70},
                },
            }
        )
    return charts
