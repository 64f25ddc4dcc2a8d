"""The test SDK: validation, parameter providers, custom actions, FixedRate and Publish."""

from __future__ import annotations

from pathlib import Path

import pytest
from redline.testing import (
    Action,
    Cartesian,
    Context,
    FixedRate,
    Param,
    ParameterSet,
    Phase,
    Publish,
    Sequence,
    Static,
    TestCase,
    ValidationError,
    validate_cases,
)
from redline.testing.cases import case_problems
from redline.testing.replay import Replay

from tests.support.actions import Repeat


class StopAfter(Action):
    """Counts its runs and sets the stop signal after ``limit`` of them."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.calls = 0

    def run(self, ctx: Context) -> None:
        self.calls += 1
        if self.calls >= self.limit:
            ctx.stop.set()


def test_validation_names_every_missing_parameter_with_case_and_phase() -> None:
    first = TestCase(
        "first",
        [
            Phase("warm", FixedRate(Param("rate"), 1, Static(b"")), warmup=True),
            Phase("load", Publish("k", Repeat(Param("text"), Param("times")))),
        ],
        Cartesian(rate=[1, 2], times=[3]),
    )
    second = TestCase("second", [Phase("only", Param("size"))], [{"size": 1}, {"other": 2}])
    with pytest.raises(ValidationError) as caught:
        validate_cases([first, second])
    problems = caught.value.problems
    assert len(problems) == 2
    assert "test case 'first', phase 'load': parameter 'text'" in problems[0]
    assert "rate=1,times=3, rate=2,times=3" in problems[0]
    assert "test case 'second', phase 'only': parameter 'size'" in problems[1]
    assert problems[1].endswith("other=2")
    assert all(p in str(caught.value) for p in problems)


def test_validation_accepts_cases_whose_parameters_are_all_provided() -> None:
    case = TestCase(
        "ok",
        [Phase("p", FixedRate(Param("rate"), Param("seconds"), Static(1)))],
        Cartesian(rate=[5], seconds=[0.1]),
    )
    validate_cases([case])


def test_validation_reports_duplicate_names_and_empty_providers() -> None:
    phase = Phase("p", Static(1))
    with pytest.raises(ValidationError) as caught:
        validate_cases([TestCase("a", [phase, phase]), TestCase("a", [phase], [])])
    text = str(caught.value)
    assert "phase 'p' is defined twice" in text
    assert "test case 'a' is defined twice" in text
    assert "yields no sets" in text


def test_cartesian_yields_every_combination_in_order_with_printable_names() -> None:
    sets = list(Cartesian(legs=[2, 8], rate=[10, 40]))
    assert sets == [
        {"legs": 2, "rate": 10},
        {"legs": 2, "rate": 40},
        {"legs": 8, "rate": 10},
        {"legs": 8, "rate": 40},
    ]
    assert [s.name for s in sets] == [
        "legs=2,rate=10",
        "legs=2,rate=40",
        "legs=8,rate=10",
        "legs=8,rate=40",
    ]
    assert ParameterSet().name == "default"


def test_cartesian_rejects_a_single_string_instead_of_a_list() -> None:
    with pytest.raises(TypeError, match="mode"):
        Cartesian(mode="fast")


def test_case_and_phase_names_must_be_usable_as_zenoh_key_chunks() -> None:
    with pytest.raises(ValueError, match="phase name"):
        Phase("a/b", Static(1))
    with pytest.raises(ValueError, match="test case name"):
        TestCase("all*", [Phase("p", Static(1))])


def test_custom_action_params_are_found_through_its_attributes_and_resolved() -> None:
    action = Sequence(Repeat(Param("text"), Param("times")), Repeat("x", 2))
    assert action.params_used() == {"text", "times"}
    assert action.run(Context(ParameterSet(text="ab", times=3))) == ["ababab", "xx"]


def test_missing_parameter_at_run_time_names_case_phase_and_parameter() -> None:
    with pytest.raises(KeyError, match="case 'c', phase 'p': parameter 'legs'"):
        Param("legs").run(Context({}, "c", "p"))


def test_fixed_rate_runs_one_iteration_per_deadline_and_reports_metrics() -> None:
    counter = StopAfter(10_000)
    ctx = Context(ParameterSet(rate=200), "c", "p")
    iterations = FixedRate(Param("rate"), 0.25, counter).run(ctx)
    assert iterations == counter.calls == 50  # deadlines at 0, 5 ms, ... 245 ms: absolute schedule
    (report,) = ctx.reports
    assert report["action"] == "FixedRate" and report["iterations"] == 50
    assert report["rate_target"] == 200 and report["rate_achieved"] > 0
    assert 0 <= report["lateness_p50_us"] <= report["lateness_p99_us"] <= report["lateness_max_us"]
    assert report["params"] == {"rate": 200} and report["interrupted"] is False


def test_fixed_rate_stops_early_when_the_run_is_stopped() -> None:
    ctx = Context(ParameterSet(), "c", "p")
    assert FixedRate(1000, 30.0, StopAfter(3)).run(ctx) == 3
    assert ctx.reports[0]["interrupted"] is True


def test_fixed_rate_rejects_a_non_positive_rate() -> None:
    with pytest.raises(ValueError, match="rate must be positive"):
        FixedRate(Param("rate"), 1, Static(1)).run(Context({"rate": 0}))


class _SilentLink:
    """A link that has put nothing: enough for an action that fails before it publishes."""

    def sent(self) -> dict[str, int]:
        return {}


def test_publish_outside_a_run_and_with_a_bad_payload_fail_clearly() -> None:
    with pytest.raises(RuntimeError, match="needs a Context with a link"):
        Publish("k", b"x").run(Context({}))
    with pytest.raises(TypeError, match="Publish\\('k'\\): payload must be bytes or str"):
        Publish("k", Static(3)).run(Context({}, link=_SilentLink()))  # type: ignore[arg-type]


def test_validation_names_every_malformed_key_expression_before_the_run() -> None:
    from redline.testing import Listen, Query, Replay, WaitFor

    case = TestCase(
        "keys",
        [
            Phase(
                "send",
                Sequence(Publish("a//b", b"x"), Publish(Param("key"), b"y"), Query("svc/*x")),
            ),
            Phase("receive", Listen("ok/**", WaitFor("bad#", 1.0))),
            Phase("replay", Replay("r.mcap", keys=["robot/$x"], remap={"robot": "sim/"})),
        ],
        Cartesian(key=["fine/key"]),
    )
    with pytest.raises(ValidationError) as caught:
        validate_cases([case])
    problems = caught.value.problems
    assert len(problems) == 6, problems
    assert problems[0].startswith(
        "test case 'keys', phase 'send': Publish: 'a//b' is not a "
        "valid key expression (empty chunks are forbidden"
    )
    assert "Query: 'svc/*x'" in problems[1] and "'*' may only" not in problems[1]
    assert "phase 'receive': WaitFor: 'bad#'" in problems[2]
    assert "Replay keys: 'robot/$x'" in problems[3] and "Replay remap: 'sim/'" in problems[4]
    assert problems[5] == "test case 'keys', phase 'replay': Replay: no recording at r.mcap"
    assert "/root/.cargo" not in str(caught.value)


def test_a_replayed_recording_is_found_beside_its_test_module_wherever_the_run_started(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A new user's `Replay("drive.mcap")` ran from the suite's folder and failed from its
    parent, 3.3 s into the run (2026-12-06): a relative recording is the test module's
    neighbour, as the suite's test modules are the suite's, and a missing one is named before
    anything runs."""
    from redline.agent.loader import load_test_cases

    perf = tmp_path / "perf"
    perf.mkdir()
    (perf / "drive.mcap").write_bytes(b"")
    (perf / "test_replay.py").write_text(
        "from redline.testing import Cartesian, Phase, Replay, TestCase\n"
        "found = TestCase('found', [Phase('go', Replay('drive.mcap'))], Cartesian(x=[1]))\n"
        "lost = TestCase('lost', [Phase('go', Replay('gone.mcap'))], Cartesian(x=[1]))\n"
    )
    monkeypatch.chdir(tmp_path)  # the suite's parent, as `redline run perf/suite.toml`
    found, lost = load_test_cases([perf / "test_replay.py"])
    replay = found.phases[0].action
    assert replay.path("drive.mcap") == perf.resolve() / "drive.mcap"
    assert case_problems(found) == []
    assert case_problems(lost) == [
        f"test case 'lost', phase 'go': Replay: no recording at gone.mcap (in {perf.resolve()}, "
        "the test module's folder)"
    ]
    assert Replay(str(perf / "drive.mcap")).missing() == []  # absolute: as given
    # a case not chosen is no reason to refuse a run: files are looked for once cases are chosen
    validate_cases([lost], files=False)
    # a suite written before: its recording where its author ran it from, and only there
    (tmp_path / "gone.mcap").write_bytes(b"")
    assert case_problems(lost) == [] and replay.path("gone.mcap") == Path("gone.mcap")
