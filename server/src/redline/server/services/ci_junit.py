"""A revision's CI verdict (`redline.server.services.ci_verdict`) as JUnit XML."""

from __future__ import annotations

from typing import Any
from xml.etree import ElementTree

from redline.recording.format import canonical_params
from redline.recording.xml_text import xml_document
from redline.server.schemas.alerts import CiVerdict


def describe(change: dict[str, Any]) -> str:
    effect = "n/a" if change["effect"] is None else f"{change['effect'] * 100:+.1f} %"
    p_value = "n/a" if change["p_value"] is None else f"{change['p_value']:.2g}"
    state, why = change["confirmation"], change["confirmation_reason"]
    confirmation = state  # the reason, when there is one, names the state itself or follows it
    if why:
        confirmation = why if why.startswith(state) else f"{state}: {why}"
    between = change.get("between")
    return (
        f"{change['process']} {change['counter']} {effect} ({change['method']}, p={p_value}, "
        f"confirmation: {confirmation})"
        + (
            f"; it may be the change of an earlier revision that did not measure it: {between}"
            if between
            else ""
        )
    )


def open_before_text(verdict: CiVerdict) -> str:
    """The regressions still open before the revision, one a line, and how many more."""
    lines = [
        f"regression #{r.id} still open before this revision ({r.confirmation}, triage: "
        f"{r.state}; after {r.good_revision}, shows at {r.bad_revision}): {r.largest}"
        + (f"; {r.changed_back}" if r.changed_back else "")
        for r in verdict.open_before
    ]
    more = verdict.open_before_total - len(verdict.open_before)
    return "\n".join(lines + ([f"and {more} more open before it"] if more > 0 else []))


def junit_xml(verdict: CiVerdict, fail_on: str = "regression") -> str:
    """One testsuite, one testcase per test case x phase x parameter set: failed (one failure
    listing every change ``fail_on`` counts: regression: for the worse; any: either way; none:
    listed, not failed), skipped with its reason where there is no verdict yet, an error where
    the host stayed busy; a pending verdict (read without waiting) a skipped testcase saying
    so. The header counts test cases, as JUnit readers do."""
    suite = ElementTree.Element(
        "testsuite", name=f"redline.{verdict.component}", tests=str(len(verdict.cases))
    )
    failures = skipped = errors = 0
    tests = len(verdict.cases)
    if verdict.state == "failed":  # no green report for a revision whose jobs never ran
        errors += 1
        tests += 1
        element = ElementTree.SubElement(
            suite, "testcase", classname=f"redline.{verdict.component}", name="performance jobs"
        )
        ElementTree.SubElement(element, "error", message=verdict.reason or "the jobs failed")
    if verdict.state == "pending":  # read without waiting: said, not an empty green report
        skipped += 1
        tests += 1
        element = ElementTree.SubElement(
            suite, "testcase", classname=f"redline.{verdict.component}", name="verdict"
        )
        why = f"pending: not judged yet, waiting for {verdict.waiting_for or 'its jobs'}"
        ElementTree.SubElement(element, "skipped", message=why)
    for case in verdict.cases:
        element = ElementTree.SubElement(
            suite,
            "testcase",
            classname=f"redline.{verdict.component}.{case.case}",
            name=f"{case.phase} {canonical_params(case.parameters)}".strip(),
        )
        if case.state == "skipped":
            skipped += 1
            ElementTree.SubElement(element, "skipped", message=case.reason)
            continue
        if case.state == "undecided":  # no green report for a measurement the host spoiled
            errors += fail_on != "none"
            kind = "error" if fail_on != "none" else "skipped"
            ElementTree.SubElement(element, kind, message=f"undecided: {case.reason}")
            skipped += kind == "skipped"
            continue
        told = [
            c
            for c in case.changes
            if (fail_on == "any" or (fail_on == "regression" and c["worse"]))
        ]
        if told:  # one failure per test case, every change it counts in its text
            failures += 1
            kinds = ["regression" if c["worse"] else "improvement" for c in told]
            kind = "regression" if "regression" in kinds else "improvement"
            message = f"{kind}: {describe(told[0])}" + (
                f" and {len(told) - 1} more" if len(told) > 1 else ""
            )
            failure = ElementTree.SubElement(element, "failure", message=message, type=kind)
            failure.text = "\n".join(
                f"{k}: {describe(c)}" for k, c in zip(kinds, told, strict=True)
            )
        rest = [c for c in case.changes if c not in told]
        if rest:
            out = ElementTree.SubElement(element, "system-out")
            out.text = "\n".join(
                ("regression: " if c["worse"] else "improvement: ") + describe(c) for c in rest
            )
    if verdict.open_before:  # not this revision's failures, but what it carries: said
        out = ElementTree.SubElement(suite, "system-out")
        out.text = open_before_text(verdict)
    suite.set("failures", str(failures))
    suite.set("skipped", str(skipped))
    suite.set("errors", str(errors))
    suite.set("tests", str(tests))
    return xml_document(suite)
