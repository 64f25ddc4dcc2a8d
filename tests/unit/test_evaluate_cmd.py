"""`redline evaluate` as a user runs it: a corpus on disk, the table and the JSON, the options,
and what a wrong corpus or method name answers."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import typer
from redline.commands.evaluate import register
from redline.detect.corpus import Corpus, SeriesLabel, write_corpus
from typer.testing import CliRunner

from tests.support import ROOT

runner = CliRunner()
app = typer.Typer()
register(app)


@app.callback()
def _redline() -> None:
    """Stands for `redline`: `evaluate` stays a subcommand."""


def _corpus(tmp_path: Path) -> Path:
    """Two series of 14 builds x 4 executions: one steps +30 % at build 8, one stays put."""
    rng = np.random.default_rng(2)
    rows = []
    for series, step in (("cpu", 1.3), ("rss", 1.0)):
        for build in range(14):
            level = 10.0 * (step if build >= 8 else 1.0)
            for execution in range(4):
                run_level = level * (1 + rng.normal(0, 0.02))
                rows += [
                    (series, build, float(v), execution) for v in rng.normal(run_level, 0.5, 10)
                ]
    frame = pd.DataFrame(rows, columns=["series", "build", "value", "execution"])
    labels = {"cpu": SeriesLabel("regression", 8), "rss": SeriesLabel("Stable")}
    write_corpus(Corpus("steps", frame, labels), tmp_path)
    return tmp_path


def test_json_names_the_default_and_scores_each_chosen_method(tmp_path: Path) -> None:
    result = runner.invoke(
        app, ["evaluate", str(_corpus(tmp_path)), "--json", "--methods", "execution_shift,ks"]
    )
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert out["default"] == "execution_shift" and out["confirm"] == 0
    assert set(out["methods"]) == {"execution_shift", "ks"}
    assert out["methods"]["execution_shift"] == {  # every figure of the table
        "roc_auc": 1.0,
        "precision": 1.0,
        "recall": 1.0,
        "f1": 1.0,
        "tp": 1,
        "fp": 0,
        "fn": 0,
        "units": 26,
        "decided": 23,
        "false_alarms_per_100": 0.0,
        "recall_large": 1.0,
        "large": 1,
    }


def test_table_reports_false_alarms_per_100_and_recall_of_large_changes(tmp_path: Path):
    result = runner.invoke(
        app,
        ["evaluate", str(_corpus(tmp_path)), "--methods", "execution_shift", "--executions", "3"],
    )
    assert result.exit_code == 0, result.output
    header, row = result.stdout.splitlines()[1:3]
    assert "FA/100" in header and "rec>=10%" in header
    # 26 units, 25 negative: no false alarm; the one +30 % change found
    assert row.split()[:2] == ["execution_shift", "1.000"]
    assert "0.0" in row.split() and "1.00" in row.split() and "(1)" in row.split()


def test_executions_option_uses_only_the_first_executions(tmp_path: Path) -> None:
    corpus = str(_corpus(tmp_path))
    one = runner.invoke(
        app, ["evaluate", corpus, "--methods", "execution_shift", "--executions", "1"]
    )
    # one execution a build: a baseline needs 6 builds, so builds 1-5 abstain in both series,
    # and cpu's builds 9-10 too: they show the change flagged at build 8, which the builds
    # after it have not yet decided; from build 11 the new level (3-5 values) is judged with
    # the old one's noise (`redline.detect.suspected`; before, builds 11-13 abstained too)
    decided = next(word for word in one.stdout.splitlines()[2].split() if "/" in word)
    assert decided == "14/26", one.output


def test_unknown_method_and_missing_corpus_are_named_with_exit_2(tmp_path: Path) -> None:
    wrong = runner.invoke(app, ["evaluate", str(_corpus(tmp_path)), "--methods", "ks,nope"])
    assert wrong.exit_code == 2 and "unknown method(s) nope" in wrong.output
    missing = runner.invoke(app, ["evaluate", str(tmp_path / "absent")])
    assert missing.exit_code == 2 and "corpus directory not found" in missing.output


def test_each_method_is_printed_when_done_and_progress_goes_to_stderr(tmp_path: Path) -> None:
    result = runner.invoke(
        app, ["evaluate", str(_corpus(tmp_path)), "--methods", "execution_shift,ks"]
    )
    assert result.exit_code == 0, result.output
    assert "execution_shift: 2/2 series" in result.stderr and "ks: 2/2 series" in result.stderr
    header, *rows = result.stdout.splitlines()[1:4]
    assert [row.split()[0] for row in rows] == ["execution_shift", "ks"]
    # no two columns run together: every header word is over its own column
    assert len(header.split()) == 11 and all(len(row.split()) >= 11 for row in rows)


def test_units_file_holds_every_units_verdict_and_confirmation(tmp_path: Path) -> None:
    units = tmp_path / "units.csv"
    corpus = str(_corpus(tmp_path / "corpus"))
    result = runner.invoke(
        app,
        [
            "evaluate",
            corpus,
            "--methods",
            "execution_shift",
            "--confirm",
            "2",
            "--units",
            str(units),
        ],
    )
    assert result.exit_code == 0, result.output
    frame = pd.read_csv(units)
    assert list(frame.columns) == [
        "series",
        "build",
        "method",
        "score",
        "flagged",
        "state",
        "positive",
    ]
    assert len(frame) == 26 and set(frame["method"]) == {"execution_shift"}
    change = frame[(frame["series"] == "cpu") & (frame["build"] == 8)].iloc[0]
    assert (change["flagged"], change["state"], change["positive"]) == (1, "held", 1)
    assert set(frame["state"]) <= {"held", "dropped", "suspected", "no change", "not enough data"}


def test_f1_scores_the_flagged_builds_as_change_points_beside_the_references(tmp_path: Path):
    result = runner.invoke(
        app,
        ["evaluate", str(_corpus(tmp_path)), "--methods", "execution_shift", "--f1", "--json"],
    )
    assert result.exit_code == 0, result.output
    points = json.loads(result.stdout)["change_point_f1"]
    assert set(points) == {"execution_shift", "zero", "binseg"}
    # cpu's one step found at its build, rss left alone: every change point right
    assert points["execution_shift"] == 1.0
    assert points["zero"] == pytest.approx((2 / 3 + 1) / 2, abs=1e-4)  # misses cpu's step


def test_several_labelled_changes_of_one_series_each_count(tmp_path: Path) -> None:
    """Up at build 8, back down at build 16: two positives, each sized between its neighbours
    (a second real change no longer counts as a false alarm)."""
    from redline.detect.corpus import load_corpus
    from redline.detect.evaluate import change_sizes, evaluate_corpus

    rng = np.random.default_rng(4)
    rows = []
    for build in range(24):
        level = 13.0 if 8 <= build < 16 else 10.0
        for execution in range(4):
            run = level * (1 + rng.normal(0, 0.02))
            rows += [("cpu", build, float(v), execution) for v in rng.normal(run, 0.5, 10)]
    frame = pd.DataFrame(rows, columns=["series", "build", "value", "execution"])
    (tmp_path / "c").mkdir()
    frame.to_parquet(tmp_path / "c" / "measurements.parquet")
    labels = {
        "cpu": {
            "label": "regression",
            "change_builds": [
                {"build": 16, "direction": "decrease"},
                {"build": 8, "direction": "increase"},
            ],
        }
    }
    (tmp_path / "c" / "labels.json").write_text(json.dumps({"name": "c", "series": labels}))
    corpus = load_corpus(str(tmp_path / "c"))
    assert corpus.labels["cpu"].change_builds == (8, 16)
    assert corpus.labels["cpu"].directions == ("increase", "decrease")
    sizes = change_sizes(corpus)
    assert sizes[("cpu", 8)] == pytest.approx(0.3, abs=0.03)
    assert sizes[("cpu", 16)] == pytest.approx(0.23, abs=0.03)  # 13 -> 10, not 10 -> 10
    scores = evaluate_corpus(corpus, ["execution_shift"])["execution_shift"]
    assert (scores.tp, scores.fp, scores.large) == (2, 0, 2)
    write_corpus(corpus, tmp_path / "again")
    assert load_corpus(str(tmp_path / "again")).labels == corpus.labels


CORPUS_2 = ROOT / "benchmarks" / "corpus" / "objectbuilder"


def _corpus_2_part(driver: bool) -> Corpus:
    """Corpus 2's driver part, or its process counters' part."""
    from dataclasses import replace

    from redline.detect.corpus import load_corpus

    corpus = load_corpus(str(CORPUS_2))
    names = {s for s, label in corpus.labels.items() if (label.process == "driver") == driver}
    frame = corpus.measurements
    kept = frame[frame["series"].isin(names)].reset_index(drop=True)
    return replace(corpus, measurements=kept)


def test_the_default_meets_the_issue_goals_on_corpus_2s_counters_part() -> None:
    """ROC-AUC >= 0.95, <= 1 false alarm per 100 unchanged revisions, >= 90 % recall of the
    changes of 10 % or more, on the committed corpus's process counters, measured on a quiet
    host (docs/detection.md): a change to a detector or to the evaluation that loses them fails
    here."""
    from redline.detect.evaluate import evaluate_corpus
    from redline.detect.registry import DEFAULT_METHOD

    scores = evaluate_corpus(_corpus_2_part(driver=False), [DEFAULT_METHOD])[DEFAULT_METHOD]
    assert scores.roc_auc >= 0.95, scores
    assert scores.false_alarms_per_100 <= 1.0, scores
    assert scores.large == 5 and scores.recall_large >= 0.9, scores


def test_the_default_finds_corpus_2s_timeouts_and_round_trip_and_no_stable_series_alarms():
    """The driver part, measured on a quiet host (docs/detection.md): one timeout per 1,000
    queries is found at its build, judged as a rate; the round trip's p50 +23 % at its build;
    no stable driver series raises an alarm (the p90's +23 % is missed: not asserted)."""
    from redline.detect.evaluate import run_detector
    from redline.detect.execution_shift import ExecutionShift

    outcomes = run_detector(ExecutionShift(), _corpus_2_part(driver=True))
    found = {
        (o.series.split("/")[0], o.series.rpartition(":")[2], o.build)
        for o in outcomes
        if o.flagged
    }
    assert ("timeouts", "timeouts", 22) in found
    assert ("rtt_plus_20", "rtt_p50_us", 11) in found
    assert not [f for f in found if f[0] == "stable"]
    assert not [f for f in found if f[0] == "rtt_plus_20" and f[2] != 11]


def test_an_unwritable_units_file_is_refused_before_the_run(tmp_path: Path) -> None:
    corpus = str(_corpus(tmp_path))
    result = runner.invoke(
        app, ["evaluate", corpus, "--units", str(tmp_path / "no" / "such" / "dir" / "u.csv")]
    )
    assert result.exit_code == 2
    assert "cannot write --units" in result.stderr and "No such file" in result.stderr
    assert result.stdout == ""  # nothing was evaluated


def test_a_change_labelled_at_a_build_the_series_skipped_counts_at_the_next_one(tmp_path: Path):
    from redline.detect.corpus import load_corpus
    from redline.detect.evaluate import change_point_f1, evaluate_corpus

    path = _corpus(tmp_path)
    frame = pd.read_parquet(path / "measurements.parquet")
    frame[frame["build"] != 8].to_parquet(path / "measurements.parquet")  # build 8 is gone
    corpus = load_corpus(str(path))
    kept: dict = {}
    scores = evaluate_corpus(
        corpus, ["execution_shift"], finished=lambda n, s, o: kept.update({n: o})
    )["execution_shift"]
    assert scores.tp == 1  # the step, labelled at 8, is found at 9
    assert change_point_f1(corpus, kept)["execution_shift"] == 1.0
