"""What the revision and execution pages say of a run: only what went unusually, legibly."""

from __future__ import annotations

from redline.server.services.revisions import run_note
from redline.server.ui.detail_figures import _fitting


def test_a_run_that_went_as_it_should_says_nothing():
    """A trial saw "ok:" beside every execution: the status said with an empty warning."""
    assert run_note({"status": "ok"}) == ""
    assert run_note({}) == ""


def test_what_went_unusually_is_said_once_each():
    assert run_note({"status": "ok", "warning": "no traffic"}) == "no traffic"
    assert run_note({"status": "interrupted"}) == "interrupted"
    assert run_note({"status": "failed", "warning": "exit 3"}) == "failed: exit 3"
    busy = run_note({"status": "ok", "disturbed_runs": 2, "disturbed_reason": "host busy: 80 %"})
    assert busy == "run again 2 time(s), the host being busy (host busy: 80 %)"


def test_a_phase_too_short_for_its_name_is_labelled_by_its_number():
    """A trial saw the execution chart's phase names, rotated, overlap on short phases."""
    name = "roundtrip/steady [rate=500]"
    assert _fitting(name, 0, share=0.5) == name  # half the run: room for it
    assert _fitting(name, 6, share=0.02) == "7"  # the name on hover (its annotation's hovertext)
