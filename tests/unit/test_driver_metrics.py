"""The driver's metrics as series, read back from real recordings written by RecordingWriter:
paths in the tree, which fields are measurements, counts as rates, CPU per unit of work, what
else used the host, and `redline compare` judging them (no service needed)."""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import typer
from redline.agent.runner import RunResult
from redline.cli import run_cmd
from redline.commands.compare import register
from redline.detect.compare import compare_files, decisive_values
from redline.detect.count_rate import CountRate
from redline.detect.counters import (
    CONTEXT_COUNTERS,
    LEVELS,
    is_count,
    judged,
    judged_among,
    kind,
    worse,
)
from redline.detect.relative_change import RelativeChange
from redline.detect.verdict import judge_series
from redline.recording import RecordingWriter, SeriesKey, read_recording
from redline.recording.disturbance import (
    OTHER_CPU,
    disturbed,
    other_load,
    other_peak,
    recording_disturbances,
)
from redline.recording.driver import DRIVER_PROCESS, report_values, series_name
from redline.recording.format import HOST_PROCESS, OWN_PROCESS
from redline.testing import Context, FixedRate, Parallel, Publish, Query, Sequence
from redline.testing.paths import action_paths
from typer.testing import CliRunner

PARAMS = {"rate": 10}
CANON = json.dumps(PARAMS, sort_keys=True, separators=(",", ":"))


QUERY_PATH = "FixedRate/Query(svc/get)"


def _query_report(
    answered: int, timeouts: int, rtt_p50: float, t_ns: int, path: str = QUERY_PATH
) -> dict:
    return {
        "t_ns": t_ns,
        "case": "c",
        "phase": "steady",
        "params": PARAMS,
        "action": "Query",
        "path": path,
        "key": "svc/get",
        "count": answered,
        "queries": answered + timeouts,
        **({"timeouts": timeouts} if timeouts else {}),
        "rtt_p50_us": rtt_p50,
        "rtt_p99_us": 3 * rtt_p50,
    }


def record(
    path: Path,
    *,
    answered: int = 100,
    timeouts: int = 0,
    rtt_p50: float = 500.0,
    cpu: float = 20.0,
    host: float = 15.0,
    own: float = 5.0,
    cores: int = 2,
    with_own: bool = True,
    query_path: str = QUERY_PATH,
    query: bool = True,
    reference: list[float] | None = None,
    rss: float | None = None,
) -> Path:
    """One execution: a 2 s 'steady' segment with component, host and own CPU samples (the
    host's with the given ``reference`` timings, in turn), and the driver's Query (at
    ``query_path`` in the tree; none without ``query``) and Publish reports."""
    rng = np.random.default_rng(int(cpu * 10 + timeouts))
    begin, end = 1_000_000_000, 3_000_000_000
    with RecordingWriter(path) as writer:
        writer.metadata("redline.run", {"component": "svc", "revision_title": path.stem})
        writer.metadata("redline.host", {"cpu_cores": str(cores)})
        writer.metadata(
            "redline.recorder", {"received": "400", "dropped": "0", "lost": "2", "sent": "200"}
        )
        writer.marker("begin", "c", "steady", PARAMS, warmup=False, t_ns=begin)
        for t_ns in range(begin + 100_000_000, end, 100_000_000):
            held = {} if rss is None else {"rss_bytes": rss + rng.normal(0, rss * 0.001)}
            writer.counters("svc", 42, {"cpu_percent": rng.normal(cpu, 0.5), **held}, t_ns)
            values = {"cpu_percent": host, "cpu_steal_percent": 0.0}
            if reference:
                values["reference_us"] = reference[t_ns // 100_000_000 % len(reference)]
            writer.counters("host", 0, values, t_ns)
            if with_own:
                writer.counters("redline", 0, {"cpu_percent": own}, t_ns)
        if query:
            writer.write_json(
                "@redline/driver/c/steady",
                _query_report(answered, timeouts, rtt_p50, end - 1000, query_path),
            )
        writer.write_json(
            "@redline/driver/c/steady",
            {
                "t_ns": end - 900,
                "case": "c",
                "phase": "steady",
                "params": PARAMS,
                "action": "Publish",
                "path": "Publish",
                "key": "svc/in",
                "published": 100,
            },
        )
        writer.marker("end", "c", "steady", PARAMS, warmup=False, t_ns=end)
    return path


def _driver(samples: dict[SeriesKey, list[float]], field: str) -> float:
    (value,) = [
        v
        for k, v in samples.items()
        if k.process == DRIVER_PROCESS and k.counter.endswith(f":{field}")
    ][0]
    return value


def test_each_action_of_a_phase_has_a_path_siblings_numbered() -> None:
    first, second = Query("svc/get"), Query("svc/get")
    root = Sequence(FixedRate(10, 1.0, first), Parallel(second, Publish("svc/in", b"x")))
    paths = action_paths(root)
    assert paths[id(first)] == "Sequence/FixedRate/Query(svc/get)"
    assert paths[id(second)] == "Sequence/Parallel/Query(svc/get)"
    twins = Sequence(Query("a"), Query("a"))
    assert sorted(action_paths(twins).values()) == [
        "Sequence",
        "Sequence/Query(a)",
        "Sequence/Query(a)#2",
    ]


def test_a_report_is_named_by_its_actions_path() -> None:
    action = Query("svc/get")
    ctx = Context(PARAMS, "c", "steady", paths={id(action): "Sequence/Query(svc/get)"})
    ctx.tally(action, "svc/get").count("queries")
    ctx.flush_metrics()
    (report,) = ctx.reports
    assert report["path"] == "Sequence/Query(svc/get)" and report["action"] == "Query"
    assert report_values(report) == {
        "count": 0.0,
        "queries": 1.0,
        "timeouts": 0.0,
        "errors": 0.0,
        "unanswered": 0.0,
    }  # no round trip measured: none reported (a "p50 0 µs" was charted as one)


def test_series_names_show_a_wildcards_concrete_key() -> None:
    assert series_name({"path": "Listen(robot/*)", "key": "robot/a"}) == "Listen(robot/*)[robot/a]"
    assert series_name({"path": "Seq/Query(a/b)", "key": "a/b"}) == "Seq/Query(a/b)"


def test_driver_metrics_become_series_one_value_per_segment(tmp_path: Path) -> None:
    samples = read_recording(record(tmp_path / "r.mcap", timeouts=3)).series_samples()
    named = {k.counter for k in samples if k.process == DRIVER_PROCESS}
    assert {
        "FixedRate/Query(svc/get):rtt_p50_us",
        "FixedRate/Query(svc/get):timeouts",
        "FixedRate/Query(svc/get):queries",
        "Publish[svc/in]:published",
    } <= named
    assert _driver(samples, "timeouts") == 3 and _driver(samples, "queries") == 103
    recorder = {k.counter: v for k, v in samples.items() if k.process == "recorder"}
    assert recorder["lost"] == [2.0] and recorder["sent"] == [200.0]


def test_a_series_kind_direction_and_whether_it_is_judged() -> None:
    assert (kind("svc"), worse("svc", "cpu_percent"), judged("svc", "cpu_percent")) == (
        "counter",
        "increase",
        True,
    )
    assert not judged("svc", "cpu_user_percent")  # the split: charted, not judged by default
    assert judged("svc", "cpu_user_percent", context=())
    assert worse(DRIVER_PROCESS, "FixedRate:rate_achieved") == "decrease"
    assert worse(DRIVER_PROCESS, "Q:rtt_p99_us") == "increase"
    assert is_count(DRIVER_PROCESS, "Q:timeouts") and not judged(DRIVER_PROCESS, "Q:queries")
    assert not judged("host", "cpu_percent") and kind("host") == "host"
    assert not judged("redline", "cpu_percent") and kind("redline") == "redline"


def test_cpu_per_unit_of_work_divides_the_components_cpu_by_what_the_driver_delivered(
    tmp_path: Path,
) -> None:
    samples = read_recording(record(tmp_path / "r.mcap", cpu=20.0)).series_samples()
    (per_op,) = [v for k, v in samples.items() if k.counter == "cpu_us_per_op"]
    # 20 % of a core over 2 s = 0.4 CPU-s, for 100 answered queries and 100 published samples
    assert per_op[0] == pytest.approx(0.4e6 / 200, rel=0.05)


def test_cpu_per_unit_of_work_is_also_given_in_units_of_the_hosts_reference_work(
    tmp_path: Path,
) -> None:
    def per_op(path: Path, counter: str) -> float:
        samples = read_recording(path).series_samples()
        ((value,),) = [v for k, v in samples.items() if k.counter == counter]
        return value

    # the host at its speed, then half as fast while the same code ran: twice the CPU for the
    # same work, and the reference work took twice as long too (its mean over the segment)
    quick = record(tmp_path / "q.mcap", cpu=20.0, reference=[280.0, 320.0])
    slow = record(tmp_path / "s.mcap", cpu=40.0, reference=[560.0, 640.0])
    assert per_op(slow, "cpu_us_per_op") == pytest.approx(2 * per_op(quick, "cpu_us_per_op"), 0.05)
    in_refs = per_op(quick, "cpu_us_per_op") / 300  # the mean (301), not the median (320)
    assert per_op(quick, "cpu_refs_per_op") == pytest.approx(in_refs, rel=0.01)
    assert per_op(slow, "cpu_refs_per_op") == pytest.approx(per_op(quick, "cpu_refs_per_op"), 0.05)
    # judged in place of the CPU time per unit of work, which is charted
    assert judged("svc", "cpu_refs_per_op") and not judged("svc", "cpu_us_per_op")
    assert not judged("host", "reference_us")
    untimed = read_recording(record(tmp_path / "u.mcap", cpu=20.0)).series_samples()
    assert not [k for k in untimed if k.counter == "cpu_refs_per_op"]  # an older recording


def test_a_cpu_share_beside_its_cpu_per_unit_of_work_at_the_hosts_speed_is_not_judged(
    tmp_path: Path,
) -> None:
    def asked(
        path: Path,
        context: tuple[str, ...] = CONTEXT_COUNTERS,
        levels: tuple[str, ...] = ("execution",),
    ) -> set[str]:
        samples = read_recording(path).series_samples()
        return {k.counter for k in judged_among(samples, context, levels) if k.process == "svc"}

    timed = record(tmp_path / "t.mcap", reference=[300.0])
    assert asked(timed) == {"cpu_refs_per_op"}  # the share is the same figure, host and all
    # a method judging samples (KS) judges the share's: the per-unit figure is one value a run
    assert asked(timed, levels=("sample",)) == {"cpu_percent"}
    assert asked(timed, levels=LEVELS) == {"cpu_percent", "cpu_refs_per_op"}
    assert asked(record(tmp_path / "u.mcap")) == {"cpu_percent"}  # no reference: the share
    # a component that does not judge the CPU at the host's speed judges its share
    assert asked(timed, (*CONTEXT_COUNTERS, "cpu_refs_per_op")) == {"cpu_percent"}


def test_redline_compare_judges_the_cpu_per_unit_of_work_only_where_both_sides_hold_enough_of_it(
    tmp_path: Path,
) -> None:
    """KS needs five values a side to find a change at its alpha (`decisive_values`); the CPU
    per unit of work is one value a recording. A reviewer found the candidate's per-unit figure
    listed as new and the share both sides held left unjudged when only the candidate's
    recordings had the host's reference: the tripled CPU passed with exit 0."""
    assert [decisive_values(a) for a in (0.01, 0.05, 0.2)] == [5, 4, 3]

    def runs(name: str, cpu: float, reference: float | None, n: int = 5) -> list[Path]:
        return [
            record(
                tmp_path / f"{name}{i}.mcap",
                cpu=cpu + i / 10,
                reference=None if reference is None else [reference],
            )
            for i in range(n)
        ]

    def changed(baseline: list[Path], candidate: list[Path]) -> set[str]:
        return {c.key.counter for c in compare_files(baseline, candidate).changed}

    # a host 30 % slower, five runs a side: the work per reference did not move, the share did
    base, slow = runs("b", 20.0, 300.0), runs("s", 26.0, 390.0)
    assert changed(base, slow) == set()
    # fewer than five a side (or one side without the reference): the share's samples decide
    assert changed(base[:4], slow[:4]) == {"cpu_percent"}
    assert changed(base[:3], slow[:3]) == {"cpu_percent"}
    # one a side: a run's samples share its level; not enough to tell a change from the noise
    (segment,) = [s for s in compare_files(base[:1], slow[:1]).segments if s.phase == "steady"]
    assert segment.changed == [] and [v.key.counter for v in segment.too_few] == ["cpu_percent"]
    assert segment.state == "undecided"
    older = runs("o", 20.0, None)  # an older agent's baseline, without the reference
    heavier = runs("h", 26.0, 300.0)
    assert changed(older, heavier) == {"cpu_percent"}
    listed = {s.key.counter for seg in compare_files(older, heavier).segments for s in seg.series}
    assert "cpu_refs_per_op" not in listed  # not "new": the share judged the CPU


def test_other_load_is_the_hosts_cpu_beyond_the_runs_own(tmp_path: Path) -> None:
    quiet = read_recording(record(tmp_path / "q.mcap", cpu=20.0, host=15.0, own=5.0))
    (other,) = [v for k, v in quiet.series_samples().items() if k.counter == OTHER_CPU]
    assert other[0] == pytest.approx(15.0 * 2 - 20.0 - 5.0, abs=1.0)  # % of one core
    assert recording_disturbances(quiet.series_samples(), 30.0) == {}
    busy = read_recording(record(tmp_path / "b.mcap", cpu=20.0, host=80.0, own=5.0))
    (reason,) = recording_disturbances(busy.series_samples(), 30.0).values()
    assert reason.startswith("host busy: other load 135 % of a core")
    blind = read_recording(record(tmp_path / "o.mcap", with_own=False))  # an older recording
    assert not [k for k in blind.series_samples() if k.counter == OTHER_CPU]


def test_a_load_that_came_and_went_within_a_phase_disturbs_it() -> None:
    """The benchmark's load (a core switched on and off every 3-30 s) over a 4-s phase: on for
    one second of it, the phase's mean other load stays under 30 % of a core, and that second
    moved the component's CPU; in a phase of a minute, one busy second does not disturb it. The
    host's CPU is a rate over its last half second, the processes' over their last tick: each is
    taken over the same window, so a heavier phase before, or a component whose CPU jumps from
    tick to tick, is no one else's load (a reviewer's case)."""

    def phase(
        seconds: int, busy: set[int], component=lambda tick: 20.0, before: float = 20.0
    ) -> list[dict]:
        """The monitor's samples at 10 Hz of the phase from 0 to ``seconds``, the ticks before
        it (the host's window reaches back into them) of a component at ``before``."""
        truth: list[float] = []  # what the host's cores did at each tick, in % of one core
        samples = []
        for tick in range(-10, seconds * 10):
            t = tick * 10**8 + 5 * 10**7
            cpu = before if tick < 0 else component(tick)
            other = 100.0 if tick >= 0 and tick // 10 in busy else 4.0
            truth.append(cpu + 5.0 + other)
            host = sum(truth[-5:]) / len(truth[-5:]) / 2  # % of both cores, over 0.5 s
            if tick >= 0:
                samples += [
                    {"t_ns": t, "process": "comp", "values": {"cpu_percent": cpu}},
                    {"t_ns": t + 1000, "process": HOST_PROCESS, "values": {"cpu_percent": host}},
                    {"t_ns": t + 2000, "process": OWN_PROCESS, "values": {"cpu_percent": 5.0}},
                ]
        return samples

    def judged(seconds: int, busy: set[int], **how) -> tuple[float, float | None, dict]:
        samples = phase(seconds, busy, **how)
        by_counter: dict = {}
        for sample in samples:
            key = (sample["process"], "cpu_percent")
            by_counter.setdefault(key, []).append(sample["values"]["cpu_percent"])
        mean = other_load(by_counter, 2)
        peak = other_peak(samples, 0, seconds * 10**9, 2)
        segment = ("case", "steady", "{}")
        return mean, peak, disturbed({segment: [mean]}, 30.0, {segment: [peak]})

    mean, peak, found = judged(4, {2})
    assert mean < 30.0 < peak, (mean, peak)  # the host's half-second windows blur the second
    assert list(found.values()) == [
        f"host busy: other load {peak:.0f} % of a core in the busiest tenth of the phase's "
        "seconds (over 30 %)"
    ]
    assert judged(60, {30})[2] == {}  # a second of a minute
    assert judged(4, set())[1:] == (pytest.approx(4.0), {})  # quiet
    heavier = judged(4, set(), before=250.0)  # after a phase at 2.5 cores
    assert heavier[1:] == (pytest.approx(4.0), {})
    jumpy = judged(4, set(), component=lambda tick: 200.0 if tick % 3 == 0 else 20.0)
    assert jumpy[1:] == (pytest.approx(4.0), {})
    assert other_peak(phase(4, set())[:3], 0, 10**8, 2) is None  # its window began before
    # just over: not "30 % ... (over 30 %)", as a new user read it
    (just,) = disturbed({("c", "p", "{}"): [30.4]}, 30.0).values()
    assert just == "host busy: other load 30.4 % of a core during the phase (over 30 %)"


def test_counts_of_rare_events_are_judged_as_rates() -> None:
    judge = CountRate()
    assert judge.compare(0, 4217, 6, 6).flagged  # every query timed out where none did
    assert not judge.compare(0, 1000, 1, 1000).flagged  # one in a thousand: not significant
    assert judge.compare(0, 10_000, 50, 10_000).direction == "increase"
    assert not judge.compare(0, 0, 1, 5).decided  # nothing sent to rate
    assert not judge.compare(5, 4, 0, 4).decided  # more events than their total
    assert judge.compare(0, 4217, 6, 6).score >= 1 > judge.compare(0, 1000, 1, 1000).score


def test_a_driver_metric_needs_three_executions_a_side_that_do_not_overlap() -> None:
    judge = RelativeChange()
    one = judge.compare([500.0], [600.0])  # a trial's unchanged code moved p90 by -34 %
    assert one.verdict == "not enough data" and "needs 3" in one.reason
    assert judge.compare([500.0, 510.0, 490.0], [600.0, 610.0, 590.0]).flagged  # +20 %, apart
    overlap = judge.compare([500.0, 700.0, 480.0], [600.0, 610.0, 590.0])
    assert overlap.verdict == "no change" and "within the baseline's range" in overlap.reason
    assert not judge.compare([500.0, 510.0, 490.0], [520.0, 530.0, 515.0]).flagged  # +4 %
    assert judge.compare([500.0] * 3, [500.0] * 3).verdict == "no change"
    assert math.isinf(judge.compare([0.0] * 3, [1.0] * 3).effect)


def test_extremes_of_a_few_hundred_samples_and_the_lateness_are_charted_not_judged() -> None:
    assert not judged(DRIVER_PROCESS, "FixedRate:lateness_max_us")
    assert not judged(DRIVER_PROCESS, "FixedRate:lateness_p50_us")  # the driver's own timing
    assert not judged(DRIVER_PROCESS, "FixedRate/Query(a):rtt_p99_us")
    assert judged(DRIVER_PROCESS, "FixedRate/Query(a):rtt_p90_us")
    assert judged(DRIVER_PROCESS, "FixedRate/Query(a):rtt_p50_us")


def test_compare_judges_a_round_trip_and_a_timeout_change(tmp_path: Path) -> None:
    base = [record(tmp_path / f"b{i}.mcap", rtt_p50=500.0 + i) for i in range(3)]
    slower = [record(tmp_path / f"s{i}.mcap", rtt_p50=600.0 + i) for i in range(3)]
    lost = [record(tmp_path / f"t{i}.mcap", answered=0, timeouts=100) for i in range(3)]
    flagged = {v.key.counter: v for v in compare_files(base, slower).changed}
    assert "FixedRate/Query(svc/get):rtt_p50_us" in flagged
    assert "FixedRate/Query(svc/get):timeouts" not in flagged
    timed_out = {v.key.counter: v for v in compare_files(base, lost).changed}
    assert timed_out["FixedRate/Query(svc/get):timeouts"].result.method == "count_rate"
    same = [record(tmp_path / f"u{i}.mcap", rtt_p50=505.0 - i) for i in range(3)]
    assert not [v for v in compare_files(base, same).changed if v.key.process == DRIVER_PROCESS]


def test_a_faster_round_trip_is_reported_but_is_no_failure(tmp_path: Path) -> None:
    base = [record(tmp_path / f"b{i}.mcap", rtt_p50=600.0 + i) for i in range(3)]
    faster = [record(tmp_path / f"f{i}.mcap", rtt_p50=500.0 + i) for i in range(3)]
    comparison = compare_files(base, faster)
    assert not [v for v in comparison.changed if v.key.process == DRIVER_PROCESS]
    (better,) = [v for v in comparison.improved if v.key.counter.endswith(":rtt_p50_us")]
    assert better.result.direction == "decrease"


def test_compare_does_not_judge_a_phase_the_host_was_busy_in(tmp_path: Path) -> None:
    """A trial saw `compare` warn that the candidate's phase was disturbed, then judge it:
    cpu_percent -23.1 %, CHANGED. A busy phase is left out, saying why."""
    base = [record(tmp_path / f"b{i}.mcap", cpu=20.0 + i / 10) for i in range(3)]
    busy = [record(tmp_path / f"h{i}.mcap", cpu=15.0, host=95.0) for i in range(3)]
    comparison = compare_files(base, busy)
    assert comparison.changed == []
    (segment,) = [s for s in comparison.segments if s.phase == "steady"]
    assert segment.series == () and "not judged: the host was busy" in segment.note
    assert "other load" in segment.note and "h0.mcap" in segment.note


def _compare(tmp_path: Path, base: list[Path], cand: list[Path]) -> tuple[int, str, ET.Element]:
    """`redline compare` on the command line: its exit code, its output and its JUnit suite."""
    app = typer.Typer()
    app.callback()(lambda: None)
    register(app)
    junit = tmp_path / "out.xml"
    args = ["compare", "--baseline", *map(str, base), "--candidate", *map(str, cand)]
    result = CliRunner().invoke(app, [*args, "--junit", str(junit)])
    suite = ET.parse(junit).getroot().find("testsuite")
    assert suite is not None, result.output
    return result.exit_code, result.output, suite


def test_compare_does_not_pass_what_a_busy_host_kept_it_from_judging(tmp_path: Path) -> None:
    """A trial compared a round trip ten times longer while another job loaded the host: every
    segment was left out, and compare printed "0 counter(s) changed", exited 0, and wrote a
    JUnit of skips. Not measured is never a pass, as `redline ci wait` says (exit 4)."""
    base = [record(tmp_path / f"b{i}.mcap", rtt_p50=500.0 + i) for i in range(3)]
    busy = [record(tmp_path / f"h{i}.mcap", rtt_p50=5000.0 + i, host=95.0) for i in range(3)]
    code, output, suite = _compare(tmp_path, base, busy)
    assert code == 4, output
    assert "segment(s) not judged (the host was busy)" in output
    assert suite.get("errors") != "0" and suite.get("skipped") == "0"
    (case,) = [c for c in suite.iter("testcase") if c.get("name") == "c/steady[rate=10]"]
    error = case.find("error")
    assert error is not None and error.get("type") == "NotJudged"
    assert "the host was busy" in error.get("message", "")


def test_compare_judges_what_the_component_holds_in_a_phase_the_host_was_busy_in(
    tmp_path: Path,
) -> None:
    """Memory does not move with other load (counters.is_held), as the service judges it: a
    leak measured on a busy host fails the comparison, its CPU is left out saying so, and the
    same memory on a busy host passes nothing (the CPU was not judged)."""
    mib = 1024 * 1024
    base = [record(tmp_path / f"b{i}.mcap", cpu=20.0 + i / 10, rss=100 * mib) for i in range(3)]
    leak = [record(tmp_path / f"l{i}.mcap", cpu=15.0, host=95.0, rss=150 * mib) for i in range(3)]
    comparison = compare_files(base, leak)
    (segment,) = [s for s in comparison.segments if s.phase == "steady"]
    assert [v.key.counter for v in segment.changed] == ["rss_bytes"]
    assert {v.key.counter for v in segment.series} == {"rss_bytes"}  # no CPU, no round trip
    assert segment.state == "failed" and segment.note.startswith("judged in part: the host")
    code, output, suite = _compare(tmp_path, base, leak)
    assert code == 1 and "CHANGED (1)" in output and "judged in part" in output, output
    (case,) = [c for c in suite.iter("testcase") if c.get("name") == "c/steady[rate=10]"]
    assert case.find("failure") is not None and case.find("error") is None
    same = [record(tmp_path / f"s{i}.mcap", cpu=15.0, host=95.0, rss=100 * mib) for i in range(3)]
    code, output, suite = _compare(tmp_path, base, same)
    assert code == 4 and "1 segment(s) judged in part (the host was busy)" in output, output
    (case,) = [c for c in suite.iter("testcase") if c.get("name") == "c/steady[rate=10]"]
    error = case.find("error")
    assert error is not None and "its CPU, rates and threads were not" in error.get("message", "")


def test_compare_does_not_pass_a_renamed_action_path(tmp_path: Path) -> None:
    """A trial moved a Query into a Sequence and tripled its round trip: compare printed
    "c/steady[rate=10]: ok", exited 0, and its JUnit counted 0 failures, judging only the series
    both sides held. The old path's series are now not judged, saying why, and fail the gate."""
    base = [record(tmp_path / f"b{i}.mcap", rtt_p50=500.0 + i) for i in range(3)]
    moved = "Sequence/Query(svc/get)"
    cand = [record(tmp_path / f"m{i}.mcap", rtt_p50=1500.0 + i, query_path=moved) for i in range(3)]
    code, output, suite = _compare(tmp_path, base, cand)
    assert code == 4, output
    assert "c/steady[rate=10]: NOT JUDGED (" in output
    assert (
        f"driver.{QUERY_PATH}:rtt_p50_us: not enough data (only in the baseline: the action "
        "path changed or the report is missing)"
    ) in output
    assert f"driver.{moved}:rtt_p50_us: not enough data (only in the candidate: " in output
    assert (suite.get("failures"), suite.get("errors")) == ("0", "1")
    (case,) = [c for c in suite.iter("testcase") if c.get("name") == "c/steady[rate=10]"]
    error = case.find("error")
    assert error is not None and error.get("type") == "NotJudged"
    assert f"driver.{QUERY_PATH}:rtt_p50_us" in error.get("message", "")
    lost = {v.key.counter: v.result for v in compare_files(base, cand).lost}
    rtt = lost[f"{QUERY_PATH}:rtt_p50_us"]
    assert rtt.verdict == "not enough data"
    assert rtt.reason == "only in the baseline: the action path changed or the report is missing"


def test_compare_does_not_pass_a_report_missing_from_every_candidate_run(tmp_path: Path) -> None:
    base = [record(tmp_path / f"b{i}.mcap", rtt_p50=500.0 + i) for i in range(3)]
    cand = [record(tmp_path / f"n{i}.mcap", query=False) for i in range(3)]
    code, output, suite = _compare(tmp_path, base, cand)
    assert code == 4, output
    assert f"driver.{QUERY_PATH}:timeouts: not enough data (only in the baseline" in output
    assert suite.get("errors") == "1"
    # the same candidate with its reports back passes: the error is the missing report's
    again = [record(tmp_path / f"q{i}.mcap", rtt_p50=505.0 - i) for i in range(3)]
    code, output, suite = _compare(tmp_path, base, again)
    assert code == 0 and suite.get("errors") == "0", output


def test_compares_junit_has_the_driver_series_a_changed_round_trip_failing(tmp_path: Path) -> None:
    timed = {"reference": [300.0]}
    # five a side: enough of the CPU per unit of work for KS (`decisive_values`)
    base = [record(tmp_path / f"b{i}.mcap", rtt_p50=500.0, **timed) for i in range(5)]
    slower = [record(tmp_path / f"s{i}.mcap", rtt_p50=600.0, **timed) for i in range(5)]
    code, output, suite = _compare(tmp_path, base, slower)
    assert code == 1, output
    (case,) = [c for c in suite.iter("testcase") if c.get("name") == "c/steady[rate=10]"]
    failure = case.find("failure")
    assert failure is not None and failure.text is not None
    (line,) = failure.text.splitlines()  # only the round trip changed
    assert line.startswith(f"driver.{QUERY_PATH}:rtt_p50_us: effect +20.0%")
    assert f"driver.{QUERY_PATH}:rtt_p50_us +20.0%" in failure.get("message", "")
    listed = (case.findtext("system-out") or "").splitlines()
    for field_name in ("timeouts", "errors", "unanswered"):  # counts, judged as rates
        assert [x for x in listed if x.startswith(f"driver.{QUERY_PATH}:{field_name}:")], listed
    assert [x for x in listed if x.startswith("svc.cpu_refs_per_op")], listed
    assert not [x for x in listed if x.startswith("svc.cpu_percent")], listed  # the same figure
    assert not [x for x in listed if x.startswith("svc.cpu_us_per_op")], listed  # charted
    assert not [x for x in listed if ":queries" in x or ":rtt_p99_us" in x]  # load, extreme


@pytest.mark.parametrize(
    ("counter", "before", "after"),
    [
        (f"{QUERY_PATH}:rtt_p50_us", 100.0, 115.0),  # +15 %, but 15 µs: under the 20 µs floor
        (f"{QUERY_PATH}:rtt_p90_us", 50.0, 60.0),
        ("FixedRate:rate_achieved", 5.0, 4.4),  # -12 %, but 0.6/s: under one per second
        ("Listen[robot/odom]:rate", 4.0, 3.5),
    ],
)
def test_a_driver_metric_moving_less_than_its_floor_is_no_change(
    counter: str, before: float, after: float
) -> None:
    base = np.array([before * 0.999, before, before * 1.001])
    cand = np.array([after * 0.999, after, after * 1.001])
    assert RelativeChange().compare(base, cand).flagged  # a change by the median's rule alone
    quiet = judge_series(RelativeChange(), counter, base, cand)
    assert quiet.verdict == "no change" and "below the absolute floor" in quiet.reason


def test_compare_does_not_fail_a_round_trip_that_moved_less_than_its_floor(tmp_path: Path) -> None:
    base = [record(tmp_path / f"b{i}.mcap", rtt_p50=100.0 + i) for i in range(3)]
    cand = [record(tmp_path / f"c{i}.mcap", rtt_p50=115.0 + i) for i in range(3)]
    comparison = compare_files(base, cand)
    assert comparison.changed == []
    (rtt,) = [v for s in comparison.segments for v in s.series if v.key.counter.endswith("p50_us")]
    assert rtt.result.verdict == "no change" and "absolute floor 20" in rtt.result.reason


def test_redline_run_prints_the_driver_table_and_warns_of_a_busy_host(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    quiet = record(tmp_path / "run-1.mcap", rtt_p50=590.0, timeouts=3, host=15.0)
    busy = record(tmp_path / "run-2.mcap", rtt_p50=610.0, host=95.0)  # 165 % other load
    results = [RunResult(path, None, 1, {}, {}) for path in (quiet, busy)]
    monkeypatch.setattr("redline.agent.runner.run_executions", lambda *a, **k: results)
    monkeypatch.delenv("REDLINE_DISTURBED_CPU_PERCENT", raising=False)
    monkeypatch.setenv("COLUMNS", "250")  # one table row a line
    run_cmd._console.cache_clear()
    try:
        run_cmd.run(tmp_path / "redline.toml", tmp_path / "run.mcap", executions=2)
    finally:
        run_cmd._console.cache_clear()
    said = capsys.readouterr().err
    (row,) = [line for line in said.splitlines() if QUERY_PATH in line]
    assert "c/steady [rate=10]" in row and "rtt p50 610 µs" in row  # the last recording's
    (warning,) = [line for line in said.splitlines() if "WARNING" in line]
    assert "c/steady" in warning and "host busy: other load 165 % of a core" in warning
    assert "charted, not judged" in warning


def test_redline_runs_table_says_what_an_action_that_measures_nothing_did() -> None:
    """A Publish measures nothing but its count: its row said "-", which read as a failure."""
    from redline.cli.run_summary import measured

    assert measured({"published": 400.0}) == "400 published"
    assert measured({"messages": 1200.0}) == "1200 messages replayed"
    # an action that measured something shows that, not its counts
    assert measured({"rate_achieved": 10.0, "iterations": 80.0}) == "10.0/s achieved"
    assert measured({}) == "-"


def test_cpu_per_op_counts_the_work_delivered_not_the_samples_listened_to(tmp_path: Path) -> None:
    """Listen's `received` counts the component's output (judged by Listen's own rate and
    losses), not work the driver delivered: counted too, a lost output would read as CPU per
    unit of work rising, and a component fed one input per output would have its work doubled."""
    path = tmp_path / "listen.mcap"
    with RecordingWriter(path) as writer:
        writer.metadata("redline.run", {"component": "svc"})
        writer.marker("begin", "c", "steady", PARAMS, warmup=False, t_ns=1_000_000_000)
        for t_ns in range(1_100_000_000, 3_000_000_000, 100_000_000):
            writer.counters("svc", 42, {"cpu_percent": 20.0}, t_ns)
        for action, counts in (("Publish", {"published": 100}), ("Listen", {"received": 300})):
            report = {"t_ns": 2_999_000_000, "case": "c", "phase": "steady", "params": PARAMS}
            writer.write_json(
                "@redline/driver/c/steady",
                {**report, "action": action, "path": action, "key": "svc/x", **counts},
            )
        writer.marker("end", "c", "steady", PARAMS, warmup=False, t_ns=3_000_000_000)
    samples = read_recording(path).series_samples()
    (per_op,) = [v for k, v in samples.items() if k.counter == "cpu_us_per_op"]
    assert per_op[0] == pytest.approx(0.4e6 / 100)  # 0.4 CPU-s over the 100 published


def test_threads_and_address_space_are_left_out_in_a_busy_phase_as_the_cpu_is():
    """A bench run (2026-12-06): a busy spell started a thread (+1 thread, +75.5 MB of address
    space), and confirmation pairs measured while the host was busy confirmed it: a false
    regression. Memory and files are judged in a busy phase still (other load does not move
    them); threads and address space, like the CPU, only in a quiet one."""
    from redline.detect.counters import left_out
    from redline.recording import SeriesKey

    def key(phase: str, counter: str, process: str = "svc") -> SeriesKey:
        return SeriesKey("c", phase, "{}", process, counter)

    keys = [
        key(phase, counter)
        for phase in ("busy", "quiet")
        for counter in ("cpu_percent", "rss_bytes", "fds", "threads", "vms_bytes")
    ] + [key("busy", "rtt_p50_us", "driver")]
    why = "host busy: other load 104 % of a core during the phase (over 30 %)"
    out = left_out(keys, {("c", "busy", "{}"): why})
    assert {(k.phase, k.counter) for k in out} == {
        ("busy", "cpu_percent"),
        ("busy", "threads"),
        ("busy", "vms_bytes"),
        ("busy", "rtt_p50_us"),
    }
    assert set(out.values()) == {why}
    assert left_out(keys, {}) == {}  # a quiet run: everything judged


def test_a_tally_of_checked_replies_counts_each_and_its_wrong_ones_from_zero() -> None:
    """A sixth trial's custom action counted its wrong replies only (`count("errors")`): 120 of
    120 wrong went unjudged (nothing to rate them out of, and no 0 where none were wrong), its
    table row said nothing of them, and the tally's empty round trips read "p50 0 µs"."""
    from redline.cli.run_summary import measured
    from redline.testing.metrics import Tally

    clean, wrong = Tally("Check", "planner/plan", "rtt"), Tally("Check", "planner/plan", "rtt")
    for reply in range(120):
        clean.checked(True)
        wrong.checked(reply % 4 == 0)
    assert (clean.summary()["queries"], clean.summary()["errors"]) == (120, 0)
    assert (wrong.summary()["queries"], wrong.summary()["errors"]) == (120, 90)
    assert not any(name.startswith("rtt_") for name in clean.summary())  # none measured
    fields = report_values({"action": "Check", **clean.summary()})
    assert fields["errors"] == 0 and fields["queries"] == 120  # a rate, from 0
    assert measured({"errors": 120.0}) == "120 errors (out of no queries counted: not judged)"
    assert measured({"errors": 3.0, "queries": 120.0}) == "3 of 120 errors"
