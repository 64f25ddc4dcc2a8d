"""`redline compare` on real recordings written by RecordingWriter: JUnit, HTML, exit codes."""

from __future__ import annotations

import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import typer
from redline.commands.compare import parse_args, register
from redline.detect.compare import CompareError, compare_files
from redline.detect.compare_junit import series_line
from redline.detect.comparison import SeriesVerdict
from redline.detect.result import NOT_ENOUGH_DATA, Detection
from redline.recording import RecordingWriter
from redline.recording.format import SeriesKey
from typer.testing import CliRunner

RATES = (10, 20)


def record(
    path: Path,
    *,
    cpu_factor: dict[int, float] | None = None,
    host_factor: float = 1.0,
    case: str = "load",
    seed: int = 0,
    rates: tuple[int, ...] = RATES,
    cores: int | None = None,
) -> Path:
    """A finished recording: a warm-up and a 'steady' phase per rate, 150 samples each, of
    component counters (cpu_percent, rss_bytes) and a host-wide cpu_percent; with ``cores``,
    also the host's cores and Redline's own CPU, from which the reader tells the other load
    (so whether the host was busy)."""
    factors = cpu_factor or {}
    rng = np.random.default_rng(seed)
    t_ns = 1_000_000_000
    with RecordingWriter(path) as writer:
        writer.metadata("redline.run", {"component": "builder", "revision_title": path.stem})
        if cores is not None:
            writer.metadata("redline.host", {"cpu_cores": str(cores)})
        for rate in rates:
            for phase, warmup in (("warmup", True), ("steady", False)):
                params = {"rate": rate}
                writer.marker("begin", case, phase, params, warmup=warmup, t_ns=t_ns)
                for _ in range(150):
                    t_ns += 10_000_000
                    cpu = factors.get(rate, 1.0) * rng.normal(rate, 1.0)
                    writer.counters(
                        "builder",
                        4242,
                        {"cpu_percent": cpu, "rss_bytes": rng.normal(50e6, 1e5)},
                        t_ns,
                    )
                    writer.counters(
                        "host", 0, {"cpu_percent": host_factor * rng.normal(30, 1)}, t_ns
                    )
                    if cores is not None:
                        writer.counters("redline", 0, {"cpu_percent": 5.0}, t_ns)
                t_ns += 10_000_000
                writer.marker("end", case, phase, params, warmup=warmup, t_ns=t_ns)
    return path


def invoke(*args: str | Path) -> tuple[int, str]:
    app = typer.Typer()
    app.callback()(lambda: None)  # keep "compare" a subcommand, as in the real CLI
    register(app)
    result = CliRunner().invoke(app, ["compare", *map(str, args)])
    return result.exit_code, result.output


@pytest.fixture
def baseline(tmp_path: Path) -> list[Path]:
    """Three runs: fewer a side cannot tell a change in CPU from run-to-run noise
    (`redline.detect.compare.MIN_RUNS`)."""
    return [record(tmp_path / f"r{i}.mcap", seed=i) for i in (1, 2, 7)]


def tripled(tmp_path: Path) -> list[Path]:
    """Three runs of the candidate whose CPU at rate 10 tripled."""
    return [record(tmp_path / f"t{i}.mcap", cpu_factor={10: 3.0}, seed=i) for i in (3, 4, 5)]


def _cases(junit: Path) -> dict[str, ET.Element]:
    root = ET.parse(junit).getroot()
    assert root.tag == "testsuites"
    return {case.get("name", ""): case for case in root.iter("testcase")}


def test_tripled_cpu_fails_only_its_parameter_set_with_effect_d_and_p(
    tmp_path: Path, baseline: list[Path]
) -> None:
    candidate = tripled(tmp_path)
    junit = tmp_path / "out.xml"
    code, output = invoke("--baseline", *baseline, "--candidate", *candidate, "--junit", junit)
    assert code == 1, output
    cases = _cases(junit)
    assert sorted(cases) == ["load/steady[rate=10]", "load/steady[rate=20]"]  # warm-up left out
    failure = cases["load/steady[rate=10]"].find("failure")
    assert failure is not None and failure.text is not None
    lines = failure.text.splitlines()
    assert len(lines) == 1 and lines[0].startswith("builder.cpu_percent: effect +")
    assert " D " in lines[0] and " p " in lines[0]
    effect = re.search(r"builder\.cpu_percent ([+-][\d.]+)%", failure.get("message", ""))
    assert effect is not None and 180 < float(effect.group(1)) < 220  # tripled: +200 %
    assert cases["load/steady[rate=20]"].find("failure") is None
    suite = ET.parse(junit).getroot().find("testsuite")
    assert suite is not None and suite.get("tests") == "2" and suite.get("failures") == "1"


def test_unchanged_candidate_passes_with_exit_zero(tmp_path: Path, baseline: list[Path]) -> None:
    junit = tmp_path / "out.xml"
    code, output = invoke("--baseline", baseline[0], "--candidate", baseline[1], "--junit", junit)
    assert code == 0, output
    cases = _cases(junit)
    assert len(cases) == 2 and all(c.find("failure") is None for c in cases.values())
    out = cases["load/steady[rate=10]"].find("system-out")
    assert out is not None and "builder.rss_bytes" in (out.text or "")


def test_host_wide_counters_are_not_judged(tmp_path: Path, baseline: list[Path]) -> None:
    candidate = record(tmp_path / "busy-host.mcap", host_factor=3.0, seed=4)
    code, output = invoke(
        "--baseline", *baseline, "--candidate", candidate, "--junit", tmp_path / "out.xml"
    )
    assert code == 0, output
    assert "host.cpu_percent" not in (tmp_path / "out.xml").read_text()


def test_html_report_is_self_contained_and_plots_the_changed_counter(
    tmp_path: Path, baseline: list[Path]
) -> None:
    candidate = tripled(tmp_path)
    report = tmp_path / "report.html"
    code, _ = invoke(
        "--baseline",
        *baseline,
        "--candidate",
        *candidate,
        "--junit",
        tmp_path / "out.xml",
        "--html",
        report,
    )
    assert code == 1
    text = report.read_text()
    assert not re.search(r"<(script|link)[^>]*\s(src|href)\s*=\s*[\"']?(https?:)?//", text)
    assert len(text) > 1_000_000  # plotly.js itself is inlined
    assert "builder.cpu_percent: raw samples" in text
    assert text.count("Plotly.newPlot") == 1 and "t3.mcap (t3)" in text


def test_truncated_recording_is_bad_input_named(tmp_path: Path, baseline: list[Path]) -> None:
    whole = record(tmp_path / "cut.mcap", seed=5).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: len(whole) // 2])
    code, output = invoke(
        "--baseline", *baseline, "--candidate", cut, "--junit", tmp_path / "out.xml"
    )
    assert code == 2
    assert "candidate recording" in output and "cut.mcap" in output and "truncated" in output
    assert not (tmp_path / "out.xml").exists()


def test_unreadable_and_missing_files_are_bad_input(tmp_path: Path, baseline: list[Path]) -> None:
    text = tmp_path / "notes.mcap"
    text.write_text("not a recording")
    for bad in (text, tmp_path / "absent.mcap"):
        code, output = invoke(
            "--baseline", bad, "--candidate", *baseline, "--junit", tmp_path / "out.xml"
        )
        assert code == 2 and f"baseline recording {bad}" in output
        assert "unpack" not in output  # the library's detail (a trial read "unpack requires a
        # buffer of 8 bytes" for a text file)
    code, output = invoke("--baseline", text, "--candidate", *baseline, "--junit", tmp_path / "o")
    assert "notes.mcap is not an MCAP file (it does not begin as one" in output, output


def test_no_common_series_is_bad_input(tmp_path: Path, baseline: list[Path]) -> None:
    other = record(tmp_path / "other.mcap", case="another-case")
    code, output = invoke(
        "--baseline", *baseline, "--candidate", other, "--junit", tmp_path / "out.xml"
    )
    assert code == 2 and "no series in common" in output


def test_arguments_take_several_files_per_side_and_repeat() -> None:
    args = parse_args(
        [
            "--baseline",
            "a.mcap",
            "b.mcap",
            "--candidate",
            "c.mcap",
            "--baseline=d.mcap",
            "--junit",
            "o.xml",
            "--html",
            "o.html",
        ]
    )
    assert args.baseline == [Path("a.mcap"), Path("b.mcap"), Path("d.mcap")]
    assert args.candidate == [Path("c.mcap")]
    assert (args.junit, args.html) == (Path("o.xml"), Path("o.html"))
    for bad in (
        ["--baseline", "a", "--candidate", "b"],
        ["x.mcap", "--junit", "o.xml"],
        ["--junit"],
        ["--baseline", "a", "--frobnicate", "--junit", "o"],
    ):
        with pytest.raises(CompareError):
            parse_args(bad)


def test_the_redline_cli_has_the_compare_command(tmp_path: Path, baseline: list[Path]) -> None:
    junit = tmp_path / "out.xml"
    result = subprocess.run(
        [
            sys.executable,
            "-c",
            "from redline.cli.main import main; main()",
            "compare",
            "--baseline",
            str(baseline[0]),
            "--candidate",
            str(baseline[1]),
            "--junit",
            str(junit),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert len(_cases(junit)) == 2


def test_a_missing_side_or_report_is_named_for_what_it_is(
    tmp_path: Path, baseline: list[Path]
) -> None:
    junit = tmp_path / "out.xml"
    for args, missing in (
        (["--baseline", *baseline], "--candidate"),
        (["--baseline", *baseline, "--junit", junit], "--candidate"),
        (["--candidate", *baseline, "--junit", junit], "--baseline"),
        (["--baseline", *baseline, "--candidate", *baseline], "--junit"),
    ):
        code, output = invoke(*args)
        assert code == 2 and f"Missing option '{missing}'" in output, output
    assert not junit.exists()


def test_a_parameter_set_the_candidate_lost_is_an_error_one_it_added_is_skipped(
    tmp_path: Path, baseline: list[Path]
) -> None:
    """A segment only the baseline recorded was a skipped testcase and exit 0: the gate passed
    what it no longer measured. Now an error (exit 4); one only the candidate has is new."""
    junit = tmp_path / "out.xml"
    fewer = record(tmp_path / "fewer.mcap", seed=3, rates=(10,))
    code, output = invoke("--baseline", *baseline, "--candidate", fewer, "--junit", junit)
    assert code == 4, output
    assert "load/steady[rate=20]: NOT JUDGED (2 only in the baseline)" in output
    assert "builder.cpu_percent: not enough data (only in the baseline: " in output
    error = _cases(junit)["load/steady[rate=20]"].find("error")
    assert error is not None and error.get("type") == "NotJudged"
    assert _cases(junit)["load/steady[rate=10]"].find("error") is None
    more = record(tmp_path / "more.mcap", seed=4, rates=(10, 20, 40))
    code, output = invoke("--baseline", *baseline, "--candidate", more, "--junit", junit)
    assert code == 0, output
    assert "load/steady[rate=40]: new (2 only in the candidate)" in output
    assert _cases(junit)["load/steady[rate=40]"].find("skipped") is not None


def test_values_apart_but_too_few_for_ks_are_undecided_not_a_pass() -> None:
    """A trial tripled its component's work per message and compared 3 runs a side: its CPU per
    unit of work (one value a run) rose 37 % with the sides apart, KS's smallest p with 3 and 3
    values is 0.1, and compare passed it as "no change". Now: not enough data, saying why, and
    the segment is undecided (exit 4); with 5 a side KS calls it; an overlap stays no change."""
    from redline.detect.compare import _judge
    from redline.detect.compare_junit import junit_xml
    from redline.detect.comparison import Comparison, SegmentVerdict, SeriesVerdict
    from redline.recording.format import SeriesKey

    key = SeriesKey("stream", "steady", '{"rate":50}', "range_filter", "cpu_us_per_op")
    three = {key: np.array([100.0, 104.0, 98.0])}
    found = _judge(key, three, {key: np.array([137.0, 140.0, 135.0])})
    assert found.verdict == "not enough data" and not found.flagged
    assert "do not overlap" in found.reason and "smallest p here: 0.1" in found.reason
    verdict = SeriesVerdict(key, found, 100.7, 137.3, 3, 3)
    segment = SegmentVerdict("stream", "steady", '{"rate":50}', (verdict,))
    assert segment.state == "undecided" and segment.too_few == [verdict]
    xml = junit_xml(Comparison((), (), (segment,)))
    assert 'type="NotJudged"' in xml and "too few values a side to decide" in xml
    five = {key: np.array([100.0, 104.0, 98.0, 101.0, 99.0])}
    called = _judge(key, five, {key: np.array([137.0, 140.0, 135.0, 138.0, 136.0])})
    assert called.flagged and called.verdict == "change"
    overlap = _judge(key, three, {key: np.array([103.0, 99.0, 101.0])})
    assert overlap.verdict == "no change"


def test_a_driver_metric_s_line_names_its_method_s_score_not_a_ks_d() -> None:
    """A trial read ``rtt_p50_us: effect +1176.9%, D 117.688``: a D of KS lies in 0..1; the
    round trip is judged by the change of its median, whose score is another thing."""
    from redline.detect.compare import _judge
    from redline.detect.compare_junit import series_line
    from redline.detect.comparison import SeriesVerdict
    from redline.recording.format import SeriesKey

    key = SeriesKey("stats", "steady", '{"rate":50}', "driver", "FixedRate/Query(s):rtt_p50_us")
    base, cand = np.array([430.0, 436.0, 441.0]), np.array([5560.0, 5570.0, 5590.0])
    found = _judge(key, {key: base}, {key: cand})
    line = series_line(SeriesVerdict(key, found, 435.7, 5573.3, 3, 3))
    assert found.flagged and " D " not in line and f"{found.method} score" in line, line


def test_a_series_not_judged_shows_no_effect() -> None:
    """A trial read "lateness_p50_us: effect +0.0% ... mean 10.124 -> 7.798 [not enough
    data: ...]": a series not judged has no effect to show."""
    verdict = SeriesVerdict(
        key=SeriesKey("c", "p", "{}", "driver", "lateness_p50_us"),
        result=Detection(method="ks", verdict=NOT_ENOUGH_DATA, reason="too few samples"),
        baseline_mean=10.124,
        candidate_mean=7.798,
        baseline_n=3,
        candidate_n=3,
    )
    line = series_line(verdict)
    assert "effect not judged" in line and "+0.0%" not in line, line


def test_a_busy_candidate_is_judged_in_part_where_both_sides_hold_what_it_holds(
    tmp_path: Path, baseline: list[Path]
) -> None:
    """Every candidate run measured on a busy host (other load near 100 % of a core): the
    rates both sides ran are judged in their memory only, saying so; the rate only the
    candidate ran has nothing to compare, and says it was not judged, not "judged in part"
    (a reviewer's find: its memory, one-sided, read as judged)."""
    busy = [
        record(tmp_path / f"b{i}.mcap", seed=10 + i, host_factor=3.0, rates=(10, 20, 40), cores=2)
        for i in range(2)
    ]
    code, output = invoke("--baseline", *baseline, "--candidate", *busy, "--junit", tmp_path / "j")
    assert code == 4, output
    assert "2 segment(s) judged in part (the host was busy)" in output, output
    assert "1 segment(s) not judged (the host was busy)" in output, output
    cases = _cases(tmp_path / "j")
    for rate in (10, 20):
        error = cases[f"load/steady[rate={rate}]"].find("error")
        assert error is not None and error.get("message", "").startswith("judged in part")
        out = cases[f"load/steady[rate={rate}]"].find("system-out")
        assert out is not None and "builder.rss_bytes" in (out.text or "")
        assert "builder.cpu_percent" not in (out.text or "")
    error = cases["load/steady[rate=40]"].find("error")
    assert error is not None and error.get("message", "").startswith("not judged: the host")


def test_runs_of_unchanged_code_at_levels_of_their_own_are_no_failure(tmp_path: Path) -> None:
    """A trial compared one recording against one of unchanged code: 9 of 15 comparisons
    failed (cpu_percent +13.6 %, p 0.0066; +37.3 % between two runs of one commit), since a
    run's samples share that run's level and KS took them for the code's. One a side is now
    too few to tell (undecided, exit 4); with three, a change must show in every run."""

    def runs(name: str, levels: list[float]) -> list[Path]:
        return [
            record(tmp_path / f"{name}{i}.mcap", cpu_factor={10: level, 20: level}, seed=i)
            for i, level in enumerate(levels)
        ]

    one, other = runs("a", [1.0]), runs("b", [1.14])  # two runs, the second 14 % busier
    code, output = invoke("--baseline", *one, "--candidate", *other, "--junit", tmp_path / "j1")
    assert code == 4, output
    assert "builder.cpu_percent: not enough data (too few values to decide: 1 and 1" in output
    assert "record more executions a side (5 and 5 suffice)" in output
    base, cand = runs("c", [1.0, 1.3, 0.95]), runs("d", [1.25, 1.05, 1.35])  # levels overlap
    comparison = compare_files(base, cand)
    assert comparison.changed == []
    overlapping = [
        v
        for segment in comparison.segments
        for v in segment.series
        if "the recordings overlap" in v.result.reason
    ]
    assert overlapping, "KS flagged the pooled samples, the runs overlapping said no change"
    assert all(v.result.verdict == "no change" for v in overlapping)
    # a change of every run is one
    worse = runs("e", [1.4, 1.45, 1.5])
    flagged = {(v.key.params, v.key.counter) for v in compare_files(base, worse).changed}
    assert flagged == {('{"rate":10}', "cpu_percent"), ('{"rate":20}', "cpu_percent")}
