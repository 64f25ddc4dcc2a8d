"""JUnit reports stay XML whatever text they carry: ElementTree writes a control character as
it is, and an audit's job reason with a build's coloured output (``\\x1b[31m``), or a case
named with ``\\x01``, made ``redline ci wait --junit`` write a file no CI could parse."""

from __future__ import annotations

from xml.etree import ElementTree

from redline.server.schemas.alerts import CaseVerdict, CiVerdict
from redline.server.services.ci_junit import junit_xml


def _parsed(document: str) -> ElementTree.Element:
    return ElementTree.fromstring(document.encode())  # refuses what is not XML


def test_a_reason_and_a_name_with_control_characters_stay_readable() -> None:
    case = CaseVerdict(
        case="build\x01", phase="steady", parameters={"p": "\ufffe"}, state="skipped", reason="?"
    )
    verdict = CiVerdict(
        component="builder",
        revision="r1",
        state="failed",
        reason="build failed: \x1b[31merror\x1b[0m\n",
        regressions=0,
        improvements=0,
        skipped=1,
        cases=[case],
        page="/",
    )
    suite = _parsed(junit_xml(verdict))
    error = suite.find("testcase/error")
    assert error is not None and error.get("message") == "build failed: \\x1b[31merror\\x1b[0m\n"
    names = [element.get("classname") for element in suite.iter("testcase")]
    assert "redline.builder.build\\x01" in names, names
    assert any("\\ufffe" in (element.get("name") or "") for element in suite.iter("testcase"))


def test_the_compare_report_stays_xml() -> None:
    """`redline compare`'s report, of a case and process named with control characters."""
    import numpy as np
    from redline.detect.compare import _judge
    from redline.detect.compare_junit import junit_xml as compare_xml
    from redline.detect.comparison import Comparison, SegmentVerdict, SeriesVerdict
    from redline.recording.format import SeriesKey

    key = SeriesKey("stream\x1b", "steady", "{}", "filter\x00", "cpu_us_per_op")
    found = _judge(key, {key: np.arange(5.0)}, {key: np.arange(5.0) * 3})
    segment = SegmentVerdict("stream\x1b", "steady", "{}", (SeriesVerdict(key, found, 2, 6, 5, 5),))
    report = _parsed(compare_xml(Comparison((), (), (segment,))))
    assert any("stream\\x1b" in (e.get("classname") or "") for e in report.iter("testcase"))


def test_the_ci_command_s_own_report_stays_xml(tmp_path) -> None:  # noqa: ANN001
    from redline.cli.ci_cmd import _junit_error

    path = tmp_path / "out.xml"
    _junit_error(path, "builder", "r1\x01", "server said: \x1b[31mno\x1b[0m")
    error = _parsed(path.read_text()).find("testcase/error")
    assert error is not None and error.get("message") == "server said: \\x1b[31mno\\x1b[0m"


def test_a_pending_verdict_read_without_waiting_says_so_and_is_no_green_report():
    """A review: `curl .../junit` of a pending verdict gave an empty suite, green to a CI reader;
    only the X-Redline-Verdict header said it was not final."""
    verdict = CiVerdict(component="builder", revision="r7", state="pending",
                        waiting_for="a performance host to take its jobs", regressions=0,
                        improvements=0, skipped=0, cases=[], page="/")  # fmt: skip
    suite = _parsed(junit_xml(verdict))
    assert (suite.get("tests"), suite.get("skipped"), suite.get("failures")) == ("1", "1", "0")
    skipped = suite.find("testcase/skipped")
    assert skipped is not None and skipped.get("message") == (
        "pending: not judged yet, waiting for a performance host to take its jobs"
    )
