"""What the demo prints and how its wait ends, without a stack."""

from __future__ import annotations

import threading

from redline.commands import demo


def test_the_demo_prints_a_change_whose_effect_is_undefined():
    change = {
        "revision": "r3",
        "series": {"label": "case/main [legs=8] p.cpu_system_percent"},
        "effect": None,
        "score": 0.95,
    }
    assert demo.change_line(change) == (
        "r3: case/main [legs=8] p.cpu_system_percent effect n/a (KS D=0.95)"
    )


def test_the_demo_says_what_confirmation_made_of_each_flagged_change():
    """A CI run's demo flagged its README-only revision at +61 %: printed as a bare "change",
    it read as a regression though the re-runs did not show it."""
    dropped = {
        "revision": "r2",
        "series": {"label": "legs_and_rate/steady[legs=8,rate=10] objectbuilder.cpu_percent"},
        "effect": 0.61,
        "score": 0.95,
        "confirmation": "dropped",
        "confirmation_reason": "not confirmed: the change showed in 0 of 2 pairs",
    }
    assert demo.change_kind(dropped) == "not confirmed"
    assert demo.change_line(dropped).endswith(
        "(KS D=0.95); not confirmed: the change showed in 0 of 2 pairs"
    )
    held = {**dropped, "confirmation": "held", "confirmation_reason": "confirmed by 2 of 2 pairs"}
    assert demo.change_kind(held) == "regression"
    assert demo.change_kind({**dropped, "confirmation": ""}) == "change"  # does not alarm
    assert demo.DEMO_DETECTION["confirm_pairs"] >= 2
    assert demo.DEMO_DETECTION["alarm_methods"] == ["ks"]


def test_the_demos_wait_ends_at_once_when_stopped():
    stop = threading.Event()
    stop.set()  # Ctrl-C while the revisions run: the demo must stop waiting, not finish them
    assert demo.wait_for_results("http://127.0.0.1:9", print, stop=stop) == []


def test_the_demo_says_why_its_newest_revision_shows_no_change():
    """A trial's demo on a busy machine ended in "r3: done" with no mark and no word why."""
    busy = "host busy: other load 104 % of a core (limit 25 %) during the phase"
    verdicts = [
        {"revision": "r3", "verdict": "not enough data", "reason": busy},
        {"revision": "r3", "verdict": "not enough data", "reason": busy},
        {"revision": "r3", "verdict": "not enough data", "reason": "missing baseline"},
    ]
    said = demo.unmarked(verdicts)
    assert said.startswith("no change marked: 2 of the 3 series of r3 were not judged (host busy")
    assert "REDLINE_DISTURBED_CPU_PERCENT" in said
    judged = [*verdicts, {"revision": "r3", "verdict": "change", "reason": ""}]
    assert demo.unmarked(judged) == ""  # the change is printed above it
    no_baseline = demo.unmarked(verdicts[2:])
    assert no_baseline.startswith("no change marked: every verdict of r3 is not enough data")
    assert "quieter" not in no_baseline  # no baseline: nothing about the host
    # its CPU undecided, its memory judged unchanged: still said (a trial's demo said nothing)
    memory = [*verdicts[:2], {"revision": "r3", "verdict": "no change", "reason": ""}]
    assert "2 of the 3 series of r3 were not judged (host busy" in demo.unmarked(memory)
    assert demo.unmarked([{"revision": "r3", "verdict": "no change", "reason": ""}]) == ""
    one = [verdicts[0], {"revision": "r3", "verdict": "no change", "reason": ""}]
    assert demo.unmarked(one).startswith("no change marked: 1 of the 2 series of r3 was not judged")
