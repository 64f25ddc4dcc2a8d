"""The self-contained HTML report of `redline compare` (the paper's analysis-tool plots).

For every compared series, the revision-evolution plot: mean ± std per recording, baseline and
candidate side by side, in the order the files were given. For every changed counter, its raw
time series in each recording (seconds since the segment began). plotly.js is inlined from the
plotly package, so the file opens anywhere, offline, with no CDN.
"""

from __future__ import annotations

import html
import json
from typing import Any

from plotly.offline import get_plotlyjs
from redline.detect.compare_junit import series_line
from redline.detect.comparison import Comparison, RecordedSeries, SegmentVerdict
from redline.server.ui.compare_figures import evolution_figure, timeseries_figure

STYLE = """body{font-family:sans-serif;margin:1.5em;max-width:1100px}
h2{margin-top:2em;border-bottom:1px solid #ccc}.changed{color:#d62728}.ok{color:#2ca02c}
.undecided{color:#b15c00}pre{background:#f6f6f6;padding:.5em;white-space:pre-wrap}.fig{height:300px}"""


def _sides(comparison: Comparison) -> list[tuple[str, RecordedSeries]]:
    return [
        *(("baseline", r) for r in comparison.baseline),
        *(("candidate", r) for r in comparison.candidate),
    ]


def _segment_html(
    segment: SegmentVerdict,
    files: list[tuple[str, RecordedSeries]],
    figures: dict[str, dict[str, Any]],
) -> str:
    changed, lost = segment.changed, segment.lost
    if changed or lost:
        said = [f"{len(changed)} changed"] if changed else []
        said += [f"{len(lost)} only in the baseline, not judged"] if lost else []
        status = f'<span class="changed">{", ".join(said)}</span>'
    else:
        status = "" if segment.note else '<span class="ok">no change</span>'
    if segment.note:  # the host was busy: not judged, or only in part; never shown as a pass
        note = f'<span class="undecided">{html.escape(segment.note)}</span>'
        status = f"{status} {note}" if status else note

    parts = [f"<h2>{html.escape(segment.name)} — {status}</h2>"]
    if segment.series:
        lines = "\n".join(
            ("CHANGED " if v.result.flagged else "        ") + series_line(v)
            for v in segment.series
        )
        parts.append(f"<pre>{html.escape(lines)}</pre>")
    for verdict in changed:
        figures[f"fig{len(figures)}"] = timeseries_figure(verdict.key, files)
        parts.append(f'<div class="fig" id="fig{len(figures) - 1}"></div>')
    for verdict in sorted(segment.series, key=lambda v: not v.result.flagged):
        figures[f"fig{len(figures)}"] = evolution_figure(verdict.key, files, verdict)
        parts.append(f'<div class="fig" id="fig{len(figures) - 1}"></div>')
    return "\n".join(parts)


def _script_json(value: Any) -> str:
    return json.dumps(value).replace("</", "<\\/")  # a "</script>" in a label must not end it


def html_report(comparison: Comparison) -> str:
    """The report as one HTML document with plotly.js and every figure inlined."""
    files = _sides(comparison)
    figures: dict[str, dict[str, Any]] = {}
    body = "\n".join(_segment_html(s, files, figures) for s in comparison.segments)
    listing = "".join(f"<li>{side}: {html.escape(str(r.path))}</li>" for side, r in files)
    changes = len(comparison.changed)
    undecided = sum(1 for segment in comparison.segments if segment.state == "undecided")
    headline = (
        f"{changes} counter(s) changed"
        if changes
        else f"no change found; {undecided} segment(s) undecided"
        if undecided
        else "no change"
    )
    plot = (
        "for (const [id, fig] of Object.entries(FIGURES)) "
        "Plotly.newPlot(id, fig.data, fig.layout, {responsive: true});"
    )
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>Redline compare: {headline}</title><style>{STYLE}</style>\n"
        f"<script>{get_plotlyjs()}</script></head>\n<body>\n"
        f"<h1>Redline compare: {headline}</h1><ul>{listing}</ul>\n{body}\n"
        f"<script>const FIGURES = {_script_json(figures)};\n{plot}</script>\n"
        f"</body></html>\n"
    )
