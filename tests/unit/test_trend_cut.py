"""How many charts one trend page draws (`redline.server.services.trend_view.cut_charts`): a
trial's import of 20,000 series made an unfiltered page of 30 MB that took 5 s to answer."""

from __future__ import annotations

from redline.server.schemas.results import SeriesRef
from redline.server.services.trend_view import MAX_CHARTS, MAX_SERIES, chart_key, cut_charts


def _refs(charts: int, lines: int, case: str = "c") -> dict[int, SeriesRef]:
    refs = {}
    for chart in range(charts):
        for line in range(lines):
            series_id = len(refs) + 1
            refs[series_id] = SeriesRef(
                id=series_id,
                label="",
                case=case,
                phase="p",
                params={"n": line},
                process="proc",
                counter=f"k{chart:05d}",
                kind="counter",
                worse="increase",
                judged=True,
            )
    return refs


def test_a_view_within_the_limits_is_drawn_whole_without_a_note():
    refs = _refs(MAX_CHARTS, MAX_SERIES // MAX_CHARTS)
    assert cut_charts(refs) == (set(refs), "")


def test_a_wide_view_draws_its_first_charts_whole_and_says_how_to_see_the_others():
    refs = _refs(5000, 4)  # the trial's 20,000 series
    drawn, note = cut_charts(refs)
    charts = {chart_key(refs[series_id]) for series_id in drawn}
    assert len(charts) == MAX_CHARTS and len(drawn) == 4 * MAX_CHARTS  # whole charts only
    assert charts == {("c", "p", "proc", f"k{n:05d}") for n in range(MAX_CHARTS)}  # the first
    assert note.startswith(
        f"This view holds 20,000 series in 5,000 charts; the page draws the first {MAX_CHARTS} "
        f"charts ({4 * MAX_CHARTS} series)."
    )
    assert "Choose a case, phase, process, counter or parameter" in note


def test_the_series_budget_ends_the_page_before_a_chart_that_would_pass_it():
    refs = _refs(MAX_CHARTS, 30)  # 30 lines a chart: the budget holds 13 whole charts
    drawn, note = cut_charts(refs)
    whole = MAX_SERIES // 30
    assert len(drawn) == 30 * whole and len({chart_key(refs[i]) for i in drawn}) == whole
    assert f"the first {whole} charts ({30 * whole} series)" in note


def test_a_first_chart_with_more_lines_than_the_budget_draws_its_first_parameter_sets():
    refs = _refs(1, MAX_SERIES + 50)
    drawn, note = cut_charts(refs)
    assert len(drawn) == MAX_SERIES and "the first 1 chart (" in note
    names = sorted(f"n={refs[i].params['n']}" for i in drawn)
    assert names == sorted(f"n={n}" for n in range(MAX_SERIES + 50))[:MAX_SERIES]


def test_the_suites_own_cases_come_before_redlines():
    refs = {**_refs(MAX_CHARTS, 1, case="@run")}
    refs.update({len(refs) + i: r for i, r in _refs(MAX_CHARTS, 1, case="zeta").items()})
    drawn, _ = cut_charts(refs)
    assert {refs[i].case for i in drawn} == {"zeta"}
