"""Choosing what a run executes (--only, --param) and how the recordings of several executions
are named (running them: tests/integration/test_runner.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
from redline.agent.runner import execution_paths
from redline.agent.selection import choose_sets, parse_overrides, select_cases
from redline.testing import Cartesian, Param, Phase, Static, TestCase, ValidationError

from tests.support import ROOT

ECHO = ROOT / "examples" / "echo" / "perf" / "redline.toml"

LOAD = TestCase("load", [Phase("p", Param("rate"))], Cartesian(legs=[2, 8], rate=[10, 40]))
IDLE = TestCase("idle", [Phase("p", Static(1))])
WARM = TestCase(
    "warm",
    [Phase("w", Param("rate"), warmup=True), Phase("p", Param("rate"))],
    Cartesian(legs=[2, 8], rate=[10, 40]),
)


def test_parse_overrides_reads_json_values_and_falls_back_to_text() -> None:
    assert parse_overrides(["rate=40", "mode=fast", "scale=0.5", "on=true"]) == {
        "rate": 40,
        "mode": "fast",
        "scale": 0.5,
        "on": True,
    }
    with pytest.raises(ValidationError, match="expected NAME=VALUE"):
        parse_overrides(["rate"])


def test_only_keeps_the_named_cases_in_suite_order() -> None:
    assert [c.name for c in select_cases([LOAD, IDLE], ["idle"])] == ["idle"]
    assert [c.name for c in select_cases([LOAD, IDLE])] == ["load", "idle"]


def test_unknown_case_and_unused_parameter_are_all_named() -> None:
    with pytest.raises(ValidationError) as caught:
        select_cases([LOAD, IDLE], ["lod"], {"rat": 1})
    assert len(caught.value.problems) == 2
    assert "--only 'lod': no such test case (the suite has: load, idle)" in str(caught.value)
    assert "--param 'rat': no chosen test case uses this parameter" in str(caught.value)


def test_override_replaces_a_value_in_every_set_and_runs_equal_sets_once() -> None:
    load, idle = select_cases([LOAD, IDLE], overrides={"rate": 25})
    assert [s.name for s in load.parameter_sets()] == ["legs=2,rate=25", "legs=8,rate=25"]
    assert idle is IDLE  # it does not use 'rate', so it is left as it is


def test_a_confirmation_run_runs_the_suite_as_far_as_the_last_named_parameter_set() -> None:
    """A confirmation run's job names the sets with a suspected change, as series name them;
    what ran before them in the flagged run runs before them again (a leak grows over a run,
    so a set measured first would not show what it showed third), what came after does not."""
    (load,) = choose_sets([LOAD, IDLE], {"load": ['{"legs":2,"rate":40}']})
    assert load.parameter_sets() == [{"legs": 2, "rate": 10}, {"legs": 2, "rate": 40}]
    (load, idle) = choose_sets([LOAD, IDLE], {"idle": ["{}"], "load": ['{"legs":2,"rate":10}']})
    assert len(load.parameter_sets()) == 4 and len(idle.parameter_sets()) == 1
    assert [len(c.parameter_sets()) for c in choose_sets([LOAD, IDLE], {})] == [4, 1]


def test_a_confirmation_run_of_a_change_per_unit_of_work_runs_the_named_sets_alone() -> None:
    """A change in CPU or a round trip does not depend on what ran before its set (its warm-up
    settles it): the named sets only, in the suite's order, each case with none named left out;
    as far as the last of them where a named case has no warm-up phase to settle it."""
    (warm,) = choose_sets([LOAD, WARM, IDLE], {"warm": ['{"legs":8,"rate":40}']}, alone=True)
    assert warm.name == "warm" and warm.phases == WARM.phases
    assert warm.parameter_sets() == [{"legs": 8, "rate": 40}]
    named = {"warm": ['{"legs":8,"rate":10}', '{"legs":2,"rate":40}']}
    (warm,) = choose_sets([WARM, LOAD], named, alone=True)
    assert warm.parameter_sets() == [{"legs": 2, "rate": 40}, {"legs": 8, "rate": 10}]
    # LOAD and IDLE have no warm-up: what ran before them runs again
    named = {"load": ['{"legs":2,"rate":40}'], "warm": ['{"legs":2,"rate":10}']}
    (load, warm) = choose_sets([LOAD, WARM, IDLE], named, alone=True)
    assert len(load.parameter_sets()) == 4 and warm.parameter_sets() == [{"legs": 2, "rate": 10}]
    with pytest.raises(ValidationError, match="has no parameter set"):
        choose_sets([WARM], {"warm": ['{"legs":4,"rate":10}']}, alone=True)


def test_a_parameter_set_or_case_the_commit_lacks_is_named() -> None:
    """The baseline's commit may have other tests: the job fails saying what is missing."""
    with pytest.raises(ValidationError) as caught:
        choose_sets([LOAD], {"load": ['{"legs":4,"rate":10}'], "gone": ["{}"]})
    assert caught.value.problems == [
        "parameter sets of 'gone': no such test case in this run",
        'test case \'load\' has no parameter set {"legs":4,"rate":10}',
    ]


def test_execution_paths_number_the_recordings_when_there_are_several() -> None:
    assert execution_paths(Path("out.mcap"), 1) == [Path("out.mcap")]
    assert execution_paths(Path("d/out.mcap"), 2) == [Path("d/out-1.mcap"), Path("d/out-2.mcap")]


def test_redline_run_names_an_unknown_case_and_parameter_and_starts_nothing(tmp_path: Path) -> None:
    from redline.cli.main import _register_all, app
    from typer.testing import CliRunner

    _register_all()
    result = CliRunner().invoke(
        app,
        [
            "run",
            str(ECHO),
            "--out",
            str(tmp_path / "x.mcap"),
            "--only",
            "pong",
            "--param",
            "sped=2",
        ],
    )
    assert result.exit_code == 2  # bad input: nothing ran
    assert "--only 'pong': no such test case (the suite has: ping, relay, replay)" in result.output
    assert "--param 'sped'" in result.output
    assert not (tmp_path / "x.mcap").exists()
