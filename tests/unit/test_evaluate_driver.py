"""`redline evaluate` judging a test driver's metrics as the service does: which way is worse,
the driver's floors, counts of rare events as a rate, loads and extremes not judged (pure: a
tiny synthetic corpus, milliseconds)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from redline.detect.corpus import Corpus, SeriesLabel, load_corpus, total_of, write_corpus
from redline.detect.evaluate import evaluate_corpus, run_detector, walk
from redline.detect.execution_shift import ExecutionShift
from redline.detect.methods import KolmogorovSmirnov

QUERY = "FixedRate/Query(svc/locate)"
BUILDS, CHANGE, EXECUTIONS, QUERIES = 14, 8, 5, 2000


def _rows(series: str, per_build: list[list[float]]) -> list[tuple[str, int, float, int]]:
    return [
        (series, build, value, execution)
        for build, values in enumerate(per_build)
        for execution, value in enumerate(values)
    ]


def _level(rng: np.random.Generator, before: float, after: float) -> list[list[float]]:
    """One value per execution (a driver's report), 2 % noise, ``after`` from build CHANGE on."""
    return [
        list(rng.normal(after if b >= CHANGE else before, 0.02 * before, EXECUTIONS))
        for b in range(BUILDS)
    ]


def _counts(before: int, after: int, lone: int | None = None) -> list[list[float]]:
    """Events per execution: ``before`` each, ``after`` from build CHANGE on; ``lone``: a build
    three of whose five executions had one event (3 in 10,000 queries, against none before)."""
    out = [[float(after if b >= CHANGE else before)] * EXECUTIONS for b in range(BUILDS)]
    if lone is not None:
        out[lone][:3] = [value + 1.0 for value in out[lone][:3]]
    return out


def _driver(field: str, label: str = "Stable", change: int | None = None) -> SeriesLabel:
    return SeriesLabel(label, change, process="driver", counter=f"{QUERY}:{field}")


def _corpus(process: str = "driver") -> Corpus:
    """Round trips that rise 30 % (a regression) or fall 30 % (an improvement); timeouts from 0
    to 2 per 2,000 queries (a regression) and a few lone ones in an otherwise clean history
    (noise); the queries (the totals, a load), a p99 (an extreme) and a lateness that rises a
    hundredfold (the driver's own timing): none of the three judged."""
    rng = np.random.default_rng(11)
    queries = [[float(QUERIES)] * EXECUTIONS for _ in range(BUILDS)]
    data = {
        f"slower/{QUERY}:rtt_p50_us": (_level(rng, 1000.0, 1300.0), "regression"),
        f"faster/{QUERY}:rtt_p50_us": (_level(rng, 1000.0, 700.0), "Stable"),
        f"late/{QUERY}:lateness_p50_us": (_level(rng, 30.0, 3000.0), "Stable"),
        f"slower/{QUERY}:rtt_p99_us": (_level(rng, 2000.0, 9000.0), "Stable"),
        f"timeouts/{QUERY}:timeouts": (_counts(0, 2), "regression"),
        f"timeouts/{QUERY}:queries": (queries, "load"),
        f"lone/{QUERY}:timeouts": (_counts(0, 0, lone=10), "Stable"),
        f"lone/{QUERY}:queries": (queries, "load"),
    }
    rows, labels = [], {}
    for series, (values, label) in data.items():
        rows += _rows(series, values)
        field, change = series.rpartition(":")[2], CHANGE if label == "regression" else None
        labels[series] = _driver(field, label, change) if process else SeriesLabel(label, change)
    frame = pd.DataFrame(rows, columns=["series", "build", "value", "execution"])
    return Corpus("driver", frame, labels)


def _alarms(corpus: Corpus, method: ExecutionShift | KolmogorovSmirnov) -> dict[str, list[int]]:
    found: dict[str, list[int]] = {}
    for o in run_detector(method, corpus):
        if o.flagged:
            found.setdefault(o.series, []).append(o.build)
    return found


def test_a_higher_round_trip_is_an_alarm_and_a_lower_one_a_change_but_no_alarm() -> None:
    corpus = _corpus()
    verdicts = {(u.series, u.build): f for u, f in walk(ExecutionShift(), corpus)}
    faster = verdicts[(f"faster/{QUERY}:rtt_p50_us", CHANGE)]
    assert faster.flagged and faster.direction == "decrease"  # the detector sees it
    alarms = _alarms(corpus, ExecutionShift())
    assert alarms[f"slower/{QUERY}:rtt_p50_us"] == [CHANGE]
    assert f"faster/{QUERY}:rtt_p50_us" not in alarms  # an improvement opens no regression


def test_a_series_that_names_no_process_counts_a_flag_either_way_as_before() -> None:
    alarms = _alarms(_corpus(process=""), ExecutionShift())
    assert alarms[f"faster/{QUERY}:rtt_p50_us"] == [CHANGE]


def test_the_driver_s_lateness_is_charted_not_judged_however_far_it_moves() -> None:
    """A bench run's unchanged revision became a regression by it (+14,526 %, confirmed by both
    pairs: its round trip, judged itself, 15 % slower in every run; `LATENESS`)."""
    judged = {u.series for u, _ in walk(ExecutionShift(), _corpus())}
    assert f"late/{QUERY}:lateness_p50_us" not in judged
    assert f"slower/{QUERY}:rtt_p50_us" in judged


def test_timeouts_are_judged_as_a_rate_out_of_the_queries_whatever_the_method() -> None:
    corpus = _corpus()
    for method in (ExecutionShift(), KolmogorovSmirnov()):
        verdicts = {(u.series, u.build): f for u, f in walk(method, corpus)}
        step = verdicts[(f"timeouts/{QUERY}:timeouts", CHANGE)]
        assert step.method == "count_rate" and step.flagged, step
        assert "0 of 20000" in step.reason and "10 of 10000" in step.reason
        assert _alarms(corpus, method)[f"timeouts/{QUERY}:timeouts"] == [CHANGE]


def test_lone_timeouts_are_no_change_as_a_rate_but_were_one_as_mostly_zero_samples() -> None:
    lone = f"lone/{QUERY}:timeouts"
    assert lone not in _alarms(_corpus(), ExecutionShift())
    assert _alarms(_corpus(process=""), ExecutionShift())[lone] == [10]


def test_loads_and_extremes_are_no_units() -> None:
    series = {u.series for u, _ in walk(ExecutionShift(), _corpus())}
    assert f"timeouts/{QUERY}:queries" not in series
    assert f"slower/{QUERY}:rtt_p99_us" not in series
    assert f"timeouts/{QUERY}:timeouts" in series


def test_a_count_without_its_total_is_not_enough_data_naming_why() -> None:
    corpus = _corpus()
    frame = corpus.measurements
    gone = frame[frame["series"] != f"timeouts/{QUERY}:queries"].reset_index(drop=True)
    verdicts = [f for u, f in walk(ExecutionShift(), Corpus("x", gone, corpus.labels))]
    counted = [f for f in verdicts if f.method == "count_rate"]
    assert counted and all(not f.decided for f in counted if "counted out of" in f.reason)
    assert any("counted out of" in f.reason for f in counted)


def test_the_total_is_found_as_the_worker_finds_it() -> None:
    label = _driver("timeouts")
    present = {f"w/{QUERY}:waits", f"w/{QUERY}:queries"}
    assert total_of(f"w/{QUERY}:timeouts", label, present) == f"w/{QUERY}:queries"
    assert total_of(f"w/{QUERY}:timeouts", label, {f"w/{QUERY}:waits"}) == f"w/{QUERY}:waits"
    assert total_of(f"w/{QUERY}:timeouts", label, set()) is None
    assert total_of("stable/cpu_percent", SeriesLabel("Stable"), present) is None


def test_the_scores_count_the_driver_series_as_the_service_judges_them() -> None:
    scores = evaluate_corpus(_corpus(), ["execution_shift"])["execution_shift"]
    assert (scores.tp, scores.fp, scores.fn) == (2, 0, 0)
    assert scores.units == 4 * (BUILDS - 1)  # two rtt, two timeouts series


def test_process_and_counter_survive_writing_and_reading_the_corpus(tmp_path: Path) -> None:
    corpus = _corpus()
    write_corpus(corpus, tmp_path)
    assert load_corpus(str(tmp_path)).labels == corpus.labels
