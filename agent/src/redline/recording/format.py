"""The layout of a Redline recording (format version 1).

An MCAP file with profile ``redline``. Every zenoh sample becomes a message on a channel whose topic
is the sample's key expression. Redline's own data travels on the run's isolated zenoh network
under ``@redline/`` (which ``**`` does not match, so components subscribing to everything never see
it) and lands on these channels, all JSON-encoded:

``@redline/counters/<process>``
    ``{"t_ns", "pid", "process", "values": {counter: number}}``, one message per monitor sample;
    a sample may lack counters that are read less often (USS/PSS, fds, context switches: ~1 Hz).
    ``@redline/counters/host`` (process ``host``, pid 0) holds the host's CPU shares and load.
``@redline/markers``
    ``{"t_ns", "event": "begin" | "end", "case", "phase", "params": {...}, "warmup": bool}``:
    the progress of the test; counter samples between a begin and its end belong to that segment.
``@redline/driver/<case>/<phase>``
    driver-side metrics, JSON objects with ``t_ns``, ``case``, ``phase``, ``params``, ``action``
    and ``path`` (the action's place in the phase's tree, `redline.testing.paths`): FixedRate
    (rates, lateness), Query (round trips, timeouts), WaitFor, Listen (received, per-key loss),
    Replay. `redline.recording.driver` turns them into series.

Metadata records: ``redline.run`` (component, revision, sort key, commit, job id, suite hash,
versions, start and end, and ``status``: ``ok``; ``no_traffic`` when every test ran but the
component showed no sign of taking part, with ``warning`` saying why (see
`redline.agent.traffic`); ``failed`` with ``error``; ``interrupted`` (SIGINT) or ``terminated``
(SIGTERM, SIGHUP) with ``signal`` and ``error``), ``redline.host`` (the host fingerprint),
``redline.recorder`` (counts of
samples received, written and dropped by the recorder; ``lost`` and ``lost_by_key`` (JSON
``{key: {"sent", "recorded"}}``) for samples the driver put that never reached it, out of
``sent`` it put in all, with ``checked_keys`` the number of keys the driver reported;
``zenoh_shared_memory`` ``on``/``off`` and ``zenoh_endpoint``, the run's router). All values
are strings, as MCAP requires.

Attachments: ``log/<process>`` (``text/plain``), the output (stdout and stderr) of each component
and fixture process of the run, its last `LOG_KEEP_BYTES` when longer (a first line says how much
was cut).
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

PROFILE = "redline"
FORMAT_VERSION = "1"
#: a commit's hash, full or abbreviated as git does (7 hex digits at least), as a run's
#: ``commit`` names it: what a forge addresses a commit status by, what one commit under two
#: names is recognised by, what the server takes a report not an admin's by, and what a host
#: checks out only as that commit's own hash (never a tag so named)
COMMIT_HASH = re.compile(r"^[0-9a-fA-F]{7,64}$")

REDLINE_PREFIX = "@redline/"
COUNTERS_PREFIX = "@redline/counters/"
MARKERS_KEY = "@redline/markers"
DRIVER_PREFIX = "@redline/driver/"

#: Not a channel: the recorder's queryable where the driver reports, at the end of a run, how many
#: samples it put per key (``{"key": count}``); the difference from what was recorded is written
#: into ``redline.recorder`` as ``lost`` and ``lost_by_key``.
RECORDER_SENT_KEY = "@redline/recorder/sent"

#: The process name under which the monitor publishes host-wide counters (CPU, steal, load):
#: the context of a run, not behaviour of the component, so detectors leave them out.
HOST_PROCESS = "host"
#: The process name under which the monitor publishes Redline's own processes' CPU (the runner
#: with its driver and router, the recorder, the monitor): context, never judged.
OWN_PROCESS = "redline"

META_RUN = "redline.run"
#: The ``status`` of a run whose every test ran while the component took no part in it.
NO_TRAFFIC = "no_traffic"
META_HOST = "redline.host"
META_RECORDER = "redline.recorder"

JSON_ENCODING = "json"

#: the attachment holding a process's output is named this followed by the process's name
LOG_ATTACHMENT_PREFIX = "log/"
#: at most this much of a process's output is kept in its recording (the end of it)
LOG_KEEP_BYTES = 256 * 1024


#: how `no_traffic_reason` begins, in every verdict's reason it is carried into
NO_TRAFFIC_MARK = "no traffic: "


def no_traffic_reason(run: Mapping[str, str]) -> str | None:
    """Why a recording's measurements say nothing of its component, from its ``redline.run``
    metadata; None unless its status is ``no_traffic``."""
    if run.get("status") != NO_TRAFFIC:
        return None
    return NO_TRAFFIC_MARK + (run.get("warning") or "the component took no part in the run")


def canonical_params(params: dict[str, Any]) -> str:
    """The canonical text of a parameter set: JSON with sorted keys and no spaces."""
    return json.dumps(params, sort_keys=True, separators=(",", ":"), default=str)


def params_name(params: dict[str, Any]) -> str:
    """The printable name of a parameter set, e.g. ``legs=4,rate=10``."""
    if not params:
        return "default"
    return ",".join(f"{key}={params[key]}" for key in sorted(params))


@dataclass(frozen=True, order=True)
class SeriesKey:
    """A series is named, never addressed by position: case, phase, parameters, process, counter."""

    case: str
    phase: str
    params: str  # canonical_params(...)
    process: str
    counter: str

    def label(self) -> str:
        params = params_name(json.loads(self.params))
        return f"{self.case}/{self.phase}[{params}] {self.process}.{self.counter}"
