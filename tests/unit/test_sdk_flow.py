"""The SDK's flow, timing, parameter and message actions, run without zenoh."""

from __future__ import annotations

import json
import threading
from typing import Any

import pytest
from redline.testing import (
    Action,
    Cartesian,
    Context,
    Filler,
    LimitedTime,
    Loop,
    Message,
    Parallel,
    Param,
    ParameterSet,
    Phase,
    Repeated,
    Sequence,
    Sleep,
    Static,
    Stop,
    Table,
    TestCase,
    ValidationError,
    WithBackground,
    validate_cases,
)


class Count(Action):
    """Counts its runs; optionally raises on the n-th."""

    def __init__(self, fail_at: int = 0) -> None:
        self.calls = 0
        self.fail_at = fail_at

    def run(self, ctx: Context) -> int:
        self.calls += 1
        if self.calls == self.fail_at:
            raise RuntimeError("boom")
        return self.calls


class Record(Action):
    """Appends a label to a shared list and returns it."""

    def __init__(self, log: list[str], label: str) -> None:
        self.log, self.label = log, label

    def run(self, ctx: Context) -> str:
        self.log.append(self.label)
        return self.label


class WaitStopped(Action):
    """Blocks until its stop signal is set; returns whether it was."""

    def run(self, ctx: Context) -> bool:
        return ctx.stop.wait(30.0)


def test_loop_runs_n_times_from_a_parameter() -> None:
    count = Count()
    assert Loop(count, Param("n")).run(Context(ParameterSet(n=7))) == 7
    assert count.calls == 7


def test_endless_loop_inside_limited_time_is_interrupted_without_stopping_the_run() -> None:
    ctx = Context({})
    count = Count()
    iterations = LimitedTime(0.1, Loop(Sequence(count, Sleep(0.005)))).run(ctx)
    assert iterations == count.calls >= 1
    assert not ctx.stopped  # only the limited subtree was stopped


def test_limited_time_interrupts_a_blocking_wait_and_returns_its_result() -> None:
    assert LimitedTime(0.05, WaitStopped()).run(Context({})) is True


def test_sleep_ends_early_when_the_run_is_stopped() -> None:
    ctx = Context({})
    timer = threading.Timer(0.05, ctx.stop.set)
    timer.start()
    assert Sleep(60).run(ctx) is False
    assert Sleep(0).run(Context({})) is True


def test_parallel_runs_every_branch_and_returns_results_in_order() -> None:
    log: list[str] = []
    result = Parallel(Record(log, "a"), Record(log, "b"), Record(log, "c")).run(Context({}))
    assert result == ["a", "b", "c"] and sorted(log) == ["a", "b", "c"]


def test_parallel_failure_stops_the_siblings_and_is_raised() -> None:
    with pytest.raises(RuntimeError, match="boom"):
        Parallel(WaitStopped(), Count(fail_at=1)).run(Context({}))


def test_with_background_interrupts_the_background_when_main_ends() -> None:
    background = Count()
    main_log: list[str] = []
    main = Sequence(Sleep(0.05), Record(main_log, "main"))
    result = WithBackground(main, Loop(Sequence(background, Sleep(0.001)))).run(Context({}))
    assert result == [True, "main"] and background.calls >= 1
    assert main_log == ["main"]


def test_with_background_raises_a_background_failure_after_main() -> None:
    with pytest.raises(RuntimeError, match="boom"):
        WithBackground(Sleep(0.01), Count(fail_at=1)).run(Context({}))


def test_stop_of_the_run_reaches_nested_children_at_once() -> None:
    run = Stop()
    child = Context({}, stop=run).child().child()
    assert not child.stopped
    run.set()
    assert child.stopped and child.stop.wait(0)


def test_child_of_a_plain_event_notices_the_parent() -> None:
    plain = threading.Event()
    child = Context({}, stop=plain).child()
    threading.Timer(0.02, plain.set).start()
    assert child.stop.wait(10.0) is True


def test_table_rows_as_dicts_or_header_and_tuples() -> None:
    assert [p.name for p in Table([{"legs": 2, "rate": 10}, {"legs": 8}])] == [
        "legs=2,rate=10",
        "legs=8",
    ]
    assert list(Table(["legs", "rate"], [(2, 10), (8, 40)])) == [
        {"legs": 2, "rate": 10},
        {"legs": 8, "rate": 40},
    ]
    with pytest.raises(ValueError, match="row 2 has 1 values for 2 columns"):
        Table(["legs", "rate"], [(2, 10), (8,)])
    with pytest.raises(TypeError, match="row 1 must be a dict"):
        Table([(2, 10)])


def test_table_rows_missing_a_parameter_fail_validation_by_row_name() -> None:
    case = TestCase("t", [Phase("p", Loop(Static(1), Param("n")))], Table([{"n": 1}, {"m": 2}]))
    with pytest.raises(
        ValidationError, match="parameter 'n' is missing from parameter set\\(s\\) m=2"
    ):
        validate_cases([case])


def test_cartesian_where_keeps_only_accepted_combinations() -> None:
    sets = Cartesian(legs=[2, 8], rate=[10, 40], where=lambda p: p["legs"] * p["rate"] <= 80)
    assert [s.name for s in sets] == ["legs=2,rate=10", "legs=2,rate=40", "legs=8,rate=10"]
    with pytest.raises(TypeError, match="where"):
        Cartesian(where=3, legs=[1])  # type: ignore[arg-type]


def test_json_message_scales_repeated_fields_and_strings_by_parameters() -> None:
    template: dict[str, Any] = {
        "legs": Repeated(lambda i: {"x": i, "y": 0.5}, Param("legs")),
        "tags": Repeated(Param("tag"), 2),
        "note": Filler(Param("size")),
        "fixed": 1,
    }
    message = Message.json(template)
    assert message.params_used() == {"legs", "tag", "size"}
    payload = message.run(Context(ParameterSet(legs=3, tag="t", size=5)))
    assert payload.encoding == "application/json"
    assert json.loads(payload) == {
        "legs": [{"x": 0, "y": 0.5}, {"x": 1, "y": 0.5}, {"x": 2, "y": 0.5}],
        "tags": ["t", "t"],
        "note": "xxxxx",
        "fixed": 1,
    }


def test_raw_message_has_the_size_of_its_parameter() -> None:
    message = Message.raw(Param("size"), fill=b"a")
    assert message.run(Context({"size": 1024})) == b"a" * 1024
    assert len(message.run(Context({"size": 0}))) == 0
    with pytest.raises(ValueError, match="must not be negative"):
        message.run(Context({"size": -1}))


def _point_cloud_class() -> Any:
    """A protobuf message class built at run time (protobuf's dynamic messages, no protoc)."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    field = descriptor_pb2.FieldDescriptorProto
    proto = descriptor_pb2.FileDescriptorProto(name="cloud_test.proto", package="redline.test")
    point = proto.message_type.add(name="Point")
    for number, name in enumerate(("x", "y"), start=1):
        point.field.add(name=name, number=number, type=field.TYPE_FLOAT)
    cloud = proto.message_type.add(name="Cloud")
    cloud.field.add(name="frame", number=1, type=field.TYPE_STRING)
    cloud.field.add(
        name="points",
        number=2,
        type=field.TYPE_MESSAGE,
        type_name=".redline.test.Point",
        label=field.LABEL_REPEATED,
    )
    pool = descriptor_pool.DescriptorPool()
    pool.Add(proto)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName("redline.test.Cloud"))


def test_protobuf_message_scales_a_repeated_field_and_decodes_back() -> None:
    cloud = _point_cloud_class()
    message = Message.protobuf(
        cloud, {"frame": Filler(3, "f"), "points": Repeated(lambda i: {"x": i, "y": 2}, Param("n"))}
    )
    small = message.run(Context({"n": 2}))
    large = message.run(Context({"n": 200}))
    assert small.encoding == "application/protobuf;redline.test.Cloud"
    decoded = cloud.FromString(bytes(small))
    assert decoded.frame == "fff" and [(p.x, p.y) for p in decoded.points] == [(0, 2), (1, 2)]
    assert len(cloud.FromString(bytes(large)).points) == 200 and len(large) > 50 * len(small)
    with pytest.raises(TypeError, match="needs a protobuf message class"):
        Message.protobuf(dict, {})
