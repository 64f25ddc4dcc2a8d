"""`redline watch`: a resource model against a live component, for faults at run time.

    redline watch --model MODEL (--process PID | --name NAME) [--zenoh-config FILE]
                  [--interval 1] [--duration S] [--json]
    redline watch --model MODEL --replay RECORDING [--json]

It opens its own zenoh session (``--zenoh-config``, else ``ZENOH_CONFIG``, else zenoh's defaults:
the live system's network, not a test's isolation), subscribes to the keys the model knows, samples
the component's process tree with the monitor's code (`redline.agent.sampling`), and every
interval predicts its CPU % and RSS from the communication. When the smoothed residual stays beyond
the threshold calibrated on the model's validation data, it prints an alarm (and when it ends).
Usage is judged by how it moves from where this process stood in its first judged steps (two
processes of the same code differ by more than the model's error), and by its level only when
gross; that first offset is printed (``{"offset": target, ...}`` with --json). It also listens to
the model's responses (keys the component answered on at every step of its training at which it
received traffic): when traffic keeps coming in and nothing goes out on one, it alarms
(``silence:KEY``), as a stall that the CPU does not show would. While the host is busy with other
work (what else used its CPU beyond its usual level by the agent's disturbance threshold), the CPU
is not judged, and it says so (``{"host": "busy", ...}``; every step has ``other_cpu_percent``).
With ``--replay`` it watches a recording instead, step by step in the recording's time
(`redline.predict.replay`): a model checked against a run of any length in seconds.
Exit status 2 on bad input (no such process, a model of another version, a recording without the
model's process); 0 when stopped.
"""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

if TYPE_CHECKING:
    from redline.predict.watch import Alarm, EventWindow, Residuals

EXIT_BAD_INPUT = 2


def _fail(message: str) -> typer.Exit:
    typer.echo(f"redline watch: {message}", err=True)
    return typer.Exit(EXIT_BAD_INPUT)


def _pid(process: int | None, name: str | None) -> int:
    import psutil

    if (process is None) == (name is None):
        raise _fail("give the component's --process PID or its --name")
    if process is not None:
        if not psutil.pid_exists(process):
            raise _fail(f"no process {process}")
        return process
    found = [p.pid for p in psutil.process_iter(["name", "cmdline"]) if _named(p, name or "")]
    found = [pid for pid in found if pid != os.getpid()]
    if len(found) != 1:
        raise _fail(
            f"{len(found)} processes are named {name!r}"
            + (f" ({', '.join(map(str, found))}): give --process PID" if found else "")
        )
    return found[0]


def _named(process: object, name: str) -> bool:
    info = getattr(process, "info", {})
    words = info.get("cmdline") or []
    return info.get("name") == name or any(Path(word).stem == name for word in words[:3])


def _reporter(server: str | None, component: str | None, process: str) -> Callable[[Alarm], None]:
    """A function that posts an alarm to the server's runtime alerts (a no-op without one);
    a failed post is said on stderr, and watching goes on."""
    import httpx

    if server is None:
        return lambda alarm: None
    if not component:
        raise _fail("--server needs --component (the component's name on the server)")
    token = os.environ.get("REDLINE_TOKEN", "")
    if not token:
        raise _fail("--server needs a token with scope 'agent' in REDLINE_TOKEN")
    client = httpx.Client(
        base_url=server.rstrip("/"), headers={"Authorization": f"Bearer {token}"}, timeout=10
    )

    def post(alarm: Alarm) -> None:
        body = {
            "target": alarm.target,
            "started": alarm.started,
            "residual": alarm.residual,
            "threshold": alarm.threshold,
            "step": alarm.step,
            "process": process,
        }
        try:
            answer = client.post(f"/api/v1/components/{component}/runtime-alerts", json=body)
            answer.raise_for_status()
        except httpx.HTTPError as error:
            typer.echo(f"could not report the alarm to {server}: {error}", err=True)

    return post


class _Sampler:
    """The component's process tree (`TreeSampler`), and what else used the host since the
    previous sample: the host's CPU less the tree's and this watcher's own
    (`redline.predict.watch.other_cpu`), judged by `Contention` (``busy``)."""

    def __init__(self, name: str, pid: int) -> None:
        from redline.agent.procstat import ProcessSampler
        from redline.agent.sampling import HostSampler, TreeSampler
        from redline.predict.watch import Contention
        from redline.recording.disturbance import threshold
        from redline.recording.format import OWN_PROCESS

        self.tree = TreeSampler(name, pid)
        self.host = HostSampler()
        self.own = ProcessSampler(OWN_PROCESS, os.getpid())
        try:
            self.contention = Contention(threshold())
        except ValueError as exc:  # REDLINE_DISTURBED_CPU_PERCENT is no number
            self.close()
            raise _fail(str(exc)) from None
        self.cores = os.cpu_count() or 0
        self.other: float | None = None
        self.busy = False

    def sample(self) -> dict[str, float]:
        """The tree's counters (OSError once the component is gone); ``other`` and ``busy``."""
        from redline.predict.watch import other_cpu

        measured = self.tree.sample()
        used = measured.get("cpu_percent", float("nan")) + self.own.sample()["cpu_percent"]
        self.other = other_cpu(self.host.sample(), used, self.cores)
        self.busy = self.contention.busy(self.other)
        return measured

    def close(self) -> None:
        self.tree.close()
        self.host.close()
        self.own.close()


def _session(config: Path | None):
    import zenoh

    if config is not None:
        return zenoh.open(zenoh.Config.from_file(str(config)))
    if os.environ.get("ZENOH_CONFIG"):
        return zenoh.open(zenoh.Config.from_env())
    return zenoh.open(zenoh.Config())


def listen(session: Any, window: EventWindow) -> list[Any]:
    """Subscribe to every key the window's features know; each sample heard is added with the
    time it arrived, stamped as the recorder stamps what it records (so that watching extracts
    from the times training did)."""
    from redline.agent.recorder import arrival_ns

    return [
        session.declare_subscriber(
            key,
            lambda sample: window.add(
                str(sample.key_expr), arrival_ns(sample), len(sample.payload.to_bytes())
            ),
        )
        for key, _ in window.spec.channels
    ]


def watch_cmd(
    model: Annotated[Path, typer.Option(help="a model file (`redline model fit`)")],
    process: Annotated[int | None, typer.Option(help="the component's process id")] = None,
    name: Annotated[str | None, typer.Option(help="the component's process name")] = None,
    zenoh_config: Annotated[
        Path | None, typer.Option(help="zenoh configuration (else ZENOH_CONFIG, else defaults)")
    ] = None,
    interval: Annotated[float, typer.Option(min=0.1, help="seconds between predictions")] = 1.0,
    duration: Annotated[
        float | None, typer.Option(min=1, help="stop after this many seconds (default: never)")
    ] = None,
    as_json: Annotated[
        bool, typer.Option("--json", help="one JSON line per step and per alarm")
    ] = False,
    server: Annotated[
        str | None,
        typer.Option(
            help="also report alarms to this Redline server (token with scope 'agent' in "
            "REDLINE_TOKEN, never on the command line)",
        ),
    ] = None,
    component: Annotated[
        str | None, typer.Option(help="the component's name on the server (with --server)")
    ] = None,
    replay: Annotated[
        Path | None,
        typer.Option(
            help="watch a recording (`redline run`) instead of a live component: every step, "
            "in the recording's time, in seconds"
        ),
    ] = None,
) -> None:
    """Watch a running component for resource faults with a model of its usage."""
    from redline.agent.interrupts import set_on_signals
    from redline.predict.dataset import RESPONSE_WINDOW_S, TARGETS, DataError
    from redline.predict.features import OUT, FeatureSpec
    from redline.predict.model import ModelFile
    from redline.predict.watch import EventWindow, Silence, Step, judge_step, trackers

    try:
        loaded = ModelFile.load(model)
    except DataError as exc:
        raise _fail(str(exc)) from None
    if replay is not None:
        _replay(loaded, replay, as_json)
        return
    pid = _pid(process, name)
    report = _reporter(server, component, loaded.process)
    window = EventWindow(loaded.spec)
    # what the component sends on at every step it receives: heard apart from the features
    answers = EventWindow(
        FeatureSpec(tuple((key, OUT) for key in loaded.responses), (RESPONSE_WINDOW_S,))
    )
    silences = [Silence(key) for key in loaded.responses]
    residuals = trackers(loaded.metrics, loaded.responses)
    stop = threading.Event()
    set_on_signals(stop, signal.SIGTERM, signal.SIGINT)
    session = _session(zenoh_config)
    subscribers = listen(session, window)
    subscribers += listen(session, answers)
    sampler = _Sampler(loaded.process, pid)
    typer.echo(
        f"watching {loaded.process} (pid {pid}) on {len(subscribers)} keys; thresholds: "
        + ", ".join(f"{t} {r.threshold:.4g}" for t, r in residuals.items())
        + "".join(f"; answers on {s.key} expected while it receives" for s in silences),
        err=True,
    )

    def say(alarm: Alarm) -> None:
        report(alarm)
        _say_alarm(alarm, as_json)

    sampler.sample()  # the CPU rate is over the time since the previous sample
    host_busy = False
    began = time.monotonic()
    # until the longest window is full, the features undercount what the component heard
    # before the watcher started: predictions too low, and an alarm for nothing
    warm_until = began + max(loaded.spec.windows)
    try:
        while not stop.wait(interval):
            try:
                measured = sampler.sample()
            except OSError:
                typer.echo(f"the component (pid {pid}) has exited", err=True)
                break
            now = time.time_ns()
            if sampler.busy != host_busy:
                host_busy = sampler.busy
                _say_host(sampler.other, sampler.contention.usual, host_busy, as_json)
            predicted = loaded.predict(window.features(now)[None, :])
            values = {t: float(measured.get(t, 0.0)) for t in TARGETS}
            guesses = {t: float(predicted[t][0]) for t in TARGETS}
            warming = time.monotonic() < warm_until
            received = window.heard(now, 1.0)
            answered = {s.key: answers.heard(now, RESPONSE_WINDOW_S, s.key) for s in silences}
            if not warming:
                unknown = [t for t in residuals.values() if t.offset is None]
                alarms = judge_step(
                    residuals, silences, values, guesses, received, answered, host_busy
                )
                for tracker in unknown:
                    if tracker.offset is not None:  # measured by this step's residual
                        _say_offset(tracker, as_json)
                for alarm in alarms:
                    say(alarm)
            if as_json:
                heard = window.heard(now, interval)
                step = Step(
                    now, warming, heard, answered, values, guesses, sampler.other, host_busy
                )
                typer.echo(json.dumps(step.line()))
            if duration is not None and time.monotonic() - began >= duration:
                break
    finally:
        for subscriber in subscribers:
            subscriber.undeclare()
        session.close()
        sampler.close()


def _say_alarm(alarm: Alarm, as_json: bool) -> None:
    said = "fault" if alarm.started else "fault over"
    typer.echo(
        json.dumps({"alarm": said, **alarm.__dict__})
        if as_json
        else f"{said}: {alarm.target} residual {alarm.residual:+.4g} "
        f"(threshold {alarm.threshold:.4g}) at step {alarm.step}"
    )


def _say_host(other: float | None, usual: float | None, busy: bool, as_json: bool) -> None:
    """The host became busy with other work (its CPU residual left out until it is not), or
    quiet again; with the other load and its usual level, from which busy is told."""
    if as_json:
        said = {"host": "busy" if busy else "quiet", "other_cpu_percent": other, "usual": usual}
        typer.echo(json.dumps(said))
        return
    load = f"other load {other or 0:.0f} % of a core, usually {usual or 0:.0f} %"
    typer.echo(
        f"host busy: {load}; the component's CPU is not judged meanwhile"
        if busy
        else f"host quiet again ({load}): the component's CPU is judged",
        err=True,
    )


def _replay(loaded: Any, recording: Path, as_json: bool) -> None:
    """``--replay``: the steps and alarms of a recording watched with the model; a summary on
    stderr. Exit 2 when the recording cannot be read or holds nothing to watch."""
    from redline.predict.dataset import DataError, read_run
    from redline.predict.replay import replay
    from redline.predict.watch import Step
    from redline.recording.reader import RecordingError

    try:
        found = replay(loaded, read_run(recording))
    except (DataError, RecordingError, OSError) as exc:
        raise _fail(f"--replay {recording}: {exc}") from None
    alarms = 0
    for item in found:
        if isinstance(item, Step):
            if as_json:
                typer.echo(json.dumps(item.line()))
            continue
        alarms += item.started
        _say_alarm(item, as_json)
    steps = sum(isinstance(item, Step) for item in found)
    typer.echo(f"replayed {steps} steps of {recording}: {alarms} alarm(s)", err=True)


def _say_offset(tracker: Residuals, as_json: bool) -> None:
    """Where this process stands against the model, now that its first steps measured it: its
    moves are judged from there (`redline.predict.watch`); beyond the threshold, a person should
    look (a fault since before watching began, or a process unlike the training run's)."""
    beyond = abs(tracker.offset or 0.0) > tracker.threshold
    if as_json:
        typer.echo(
            json.dumps(
                {"offset": tracker.target, "value": tracker.offset,
                 "taken_off": tracker.taken_off, "threshold": tracker.threshold,
                 "beyond": beyond}
            )
        )  # fmt: skip
        return
    typer.echo(
        f"{tracker.target}: this process stands {tracker.offset:+.4g} from the model's "
        f"prediction (threshold {tracker.threshold:.4g}); its moves are judged from here"
        + (": beyond the threshold from the start, look at it" if beyond else ""),
        err=not beyond,
    )


def register(app: typer.Typer) -> None:
    app.command("watch")(watch_cmd)
