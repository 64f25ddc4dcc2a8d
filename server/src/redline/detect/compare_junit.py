"""JUnit XML for `redline compare`: what Jenkins, GitLab and GitHub read as test results.

One testcase per test case × phase × parameter set (classname: the test case; name:
``case/phase[params]`` with the printable parameter-set name), by its `SegmentVerdict.state`: a
failure lists the counters that changed for the worse with their effect size, KS D and p; an
error (``NotJudged``) lists the series only the baseline holds, where nothing changed for the
worse (a renamed action path, a report missing from the candidate), and a segment the host
was busy in: never a silent pass; a segment only the candidate recorded is skipped; every series
is listed in the testcase's system-out.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

from redline.detect.comparison import Comparison, SegmentVerdict, SeriesVerdict
from redline.detect.result import NOT_ENOUGH_DATA
from redline.recording.xml_text import xml_document

SUITE_NAME = "redline compare"


def series_line(verdict: SeriesVerdict) -> str:
    """``process.counter: effect +200.0%, D 0.950, p 1.2e-30; mean 20 -> 60 (n 200 -> 200)``,
    and the reason when KS did not decide (too few samples, constant) or the floor held it."""
    result, key = verdict.result, verdict.key
    p_value = "n/a" if result.p_value is None else f"{result.p_value:.3g}"
    reason = f" [{result.verdict}: {result.reason}]" if result.reason else ""
    before, after = (
        f"{mean:.6g}" if n else "-"
        for mean, n in (
            (verdict.baseline_mean, verdict.baseline_n),
            (verdict.candidate_mean, verdict.candidate_n),
        )
    )
    # KS's score is its D (0..1); the driver's metrics are judged by another method's score
    score = (
        f"D {result.score:.3f}"
        if result.method == "ks"
        else f"{result.method} score {result.score:.3g}"
    )
    # a series not judged has no effect: a trial read "+0.0%" beside means 10.1 -> 7.8
    effect = "not judged" if result.verdict == NOT_ENOUGH_DATA else f"{result.effect:+.1%}"
    return (
        f"{key.process}.{key.counter}: effect {effect}, {score}, "
        f"p {p_value}; mean {before} -> {after} "
        f"(n {verdict.baseline_n} -> {verdict.candidate_n}){reason}"
    )


def _testcase(parent: ET.Element, segment: SegmentVerdict) -> None:
    case = ET.SubElement(parent, "testcase", classname=segment.case, name=segment.name, time="0")
    changed, state = segment.changed, segment.state
    if state == "undecided":  # the host was busy, or series not judged: never a pass
        lost, few = segment.lost, segment.too_few
        said = [f"{len(lost)} series only in the baseline"] if lost else []
        said += [f"{len(few)} with too few values a side to decide"] if few else []
        named = ", ".join(f"{v.key.process}.{v.key.counter}" for v in (*lost, *few))
        message = [segment.note] if segment.note else []
        message += [f"{', '.join(said)}, not judged: {named}"] if said else []
        error = ET.SubElement(case, "error", type="NotJudged", message="; ".join(message))
        error.text = "\n".join(series_line(v) for v in (*lost, *few))
        if not segment.series:
            return
    elif state == "skipped":
        ET.SubElement(case, "skipped", message="recorded only in the candidate: nothing to compare")
    if changed:
        names = ", ".join(
            f"{v.key.process}.{v.key.counter} {v.result.effect:+.1%}" for v in changed
        )
        failure = ET.SubElement(
            case,
            "failure",
            type="PerformanceChange",
            message=f"{len(changed)} counter(s) changed: {names}",
        )
        failure.text = "\n".join(series_line(v) for v in changed)
    out = ET.SubElement(case, "system-out")
    out.text = "\n".join(
        [*([segment.note] if segment.note else []), *map(series_line, segment.series)]
    )


def junit_xml(comparison: Comparison) -> str:
    """The whole report as an XML document (UTF-8 text with its declaration)."""
    segments = comparison.segments
    suite = ET.Element(
        "testsuite",
        name=SUITE_NAME,
        tests=str(len(segments)),
        failures=str(sum(1 for s in segments if s.state == "failed")),
        errors=str(sum(1 for s in segments if s.state == "undecided")),
        skipped=str(sum(1 for s in segments if s.state == "skipped")),
        time="0",
    )
    properties = ET.SubElement(suite, "properties")
    for side, recorded in (("baseline", comparison.baseline), ("candidate", comparison.candidate)):
        for item in recorded:
            ET.SubElement(properties, "property", name=side, value=str(item.path))
    for segment in segments:
        _testcase(suite, segment)
    suites = ET.Element(
        "testsuites",
        name=SUITE_NAME,
        tests=suite.get("tests", "0"),
        failures=suite.get("failures", "0"),
        errors=suite.get("errors", "0"),
    )
    suites.append(suite)
    ET.indent(suites)
    return xml_document(suites) + "\n"
