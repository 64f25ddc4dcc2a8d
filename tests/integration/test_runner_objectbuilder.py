"""The runner on the objectbuilder example end to end: one real run (component, zenoh router,
recorder, monitor) whose recording the tests read.

Serial: the component's CPU per configuration is compared, which other tests' load would move.
"""

from __future__ import annotations

import pytest
from redline.agent.runner import RunResult, run_suite
from redline.recording import Recording, canonical_params, read_recording

from tests.support import ROOT

OBJECTBUILDER = ROOT / "examples" / "objectbuilder" / "perf" / "redline.toml"

pytestmark = pytest.mark.serial


@pytest.fixture(scope="module")
def objectbuilder_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[RunResult, Recording]:
    out = tmp_path_factory.mktemp("run") / "objectbuilder.mcap"
    result = run_suite(OBJECTBUILDER, out, run_metadata={"revision_title": "r1", "job_id": "7"})
    return result, read_recording(out)


def test_recording_holds_counters_for_every_measured_segment(objectbuilder_run) -> None:
    _, recording = objectbuilder_run
    samples = recording.series_samples()
    measured = [s for s in recording.segments() if not s.warmup]
    assert len(measured) == 4
    for segment in measured:
        for counter in ("cpu_percent", "rss_bytes", "threads"):
            values = [
                v
                for k, v in samples.items()
                if k.process == "objectbuilder"
                and k.counter == counter
                and k.phase == segment.phase
                and k.params == canonical_params(segment.params)
            ]
            assert values and values[0], f"no {counter} in {segment}"
    processes = {c["process"] for c in recording.counters}
    assert processes == {"objectbuilder", "host", "redline"}  # redline: the run's own CPU
    assert all(c["pid"] > 0 for c in recording.counters if c["process"] == "objectbuilder")
    counters = {k.counter for k in samples if k.process == "objectbuilder"}
    assert {
        "cpu_user_percent",
        "cpu_system_percent",
        "vms_bytes",
        "uss_bytes",
        "pss_bytes",
        "ctx_voluntary_per_s",
        "ctx_involuntary_per_s",
        "fds",
        "processes",
    } <= counters
    assert {"cpu_steal_percent", "load_1m"} <= {k.counter for k in samples if k.process == "host"}


def test_recording_holds_markers_traffic_and_driver_metrics(objectbuilder_run) -> None:
    _, recording = objectbuilder_run
    names = {
        (s.phase, f"legs={s.params['legs']},rate={s.params['rate']}") for s in recording.segments()
    }
    expected = {f"legs={legs},rate={rate}" for legs in (2, 8) for rate in (10, 40)}
    assert names == {(phase, name) for phase in ("warmup", "steady") for name in expected}
    assert recording.traffic["objectbuilder/legs"] > 0
    assert recording.traffic["objectbuilder/persons"] > 0
    steady = [d for d in recording.driver if d["phase"] == "steady"]
    rates = [d for d in steady if d["action"] == "FixedRate"]
    assert len(rates) == 4 and {d["iterations"] for d in rates} == {20, 80}  # 2 s, 10 and 40 Hz
    published = [d for d in steady if d["action"] == "Publish"]  # what FixedRate put, per key
    assert {d["key"] for d in published} == {"objectbuilder/legs", "objectbuilder/pose"}
    assert len(published) == 8 and {d["published"] for d in published} == {20, 80}


def test_each_parameter_set_is_warmed_up_right_before_it_is_measured(objectbuilder_run) -> None:
    _, recording = objectbuilder_run
    ordered = sorted(recording.segments(), key=lambda s: s.begin_ns)
    assert [s.phase for s in ordered] == ["warmup", "steady"] * 4
    pairs = zip(ordered[::2], ordered[1::2], strict=True)
    assert all(warm.params == steady.params for warm, steady in pairs)


def test_recording_metadata_names_run_host_and_recorder(objectbuilder_run) -> None:
    result, recording = objectbuilder_run
    run = recording.run
    assert run["revision_title"] == "r1" and run["job_id"] == "7"
    assert run["component"] == "objectbuilder" and run["suite"] == "objectbuilder"
    assert len(run["suite_sha256"]) == 64 and run["status"] == "ok"
    assert run["zenoh_version"] and run["redline_version"] and run["ended_at"] > run["started_at"]
    host = recording.metadata["redline.host"]
    assert host["governor_state"] in {"pinned", "unavailable", "denied"}
    assert int(host["cpu_cores"]) >= 1 and host["kernel"] and "load_1m" in host
    counts = recording.metadata["redline.recorder"]
    assert int(counts["written"]) == int(counts["received"]) - int(counts["dropped"]) > 0
    assert result.workspace is None  # removed after a successful run


def test_cpu_grows_with_the_number_of_legs(objectbuilder_run) -> None:
    _, recording = objectbuilder_run
    means = {}
    for key, values in recording.series_samples().items():
        if key.counter == "cpu_percent" and key.process == "objectbuilder":
            means[key.params] = sum(values) / len(values)
    for rate in (10, 40):  # 28 leg pairs against 1: the quadratic work must show at each rate
        few = means[f'{{"legs":2,"rate":{rate}}}']
        many = means[f'{{"legs":8,"rate":{rate}}}']
        assert many > 2 * few, means
