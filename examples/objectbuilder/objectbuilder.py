"""objectbuilder: a data-fusion mock after Wienke & Wrede's example component.

Subscribes to leg detections (``objectbuilder/legs``, JSON ``{"stamp", "legs": [{"x", "y"}]}``) and
robot poses (``objectbuilder/pose``, JSON ``{"x", "y", "theta"}``), pairs up legs into person
hypotheses in world coordinates, and publishes them on ``objectbuilder/persons``. The work per leg
message grows with the square of the number of legs (every pair is scored, `tuning.WORK_PER_PAIR`
steps each). Leg messages are processed by a thread pool (``--threads``), poses by one thread.

Queryable ``objectbuilder/locate``: the same fusion on request (a leg message as the query's
payload, the persons as the reply), after `tuning.REPLY_DELAY_US` of waiting; with
`tuning.DROP_EVERY` = N, every Nth query is left unanswered until the caller has timed out.

Opens zenoh with ``zenoh.Config.from_env()`` (``ZENOH_CONFIG``), prints ``objectbuilder ready``
once its subscribers and publisher are declared, and exits cleanly on SIGTERM or SIGINT.

``--faults FILE`` lets a test inject a resource fault into the running component (for
`redline watch`): while FILE exists and names one, ``busy`` spins a thread (CPU its traffic does
not explain) in native code, off the GIL, ``leak`` keeps 256 KiB more every 50 ms, and ``stall``
blocks the leg workers (its messages queue up unprocessed).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import signal
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import tuning
import zenoh
from tuning import WORK_PER_PAIR

LEGS_KEY = "objectbuilder/legs"
POSE_KEY = "objectbuilder/pose"
PERSONS_KEY = "objectbuilder/persons"
LOCATE_KEY = "objectbuilder/locate"
REPLY_DELAY_S = getattr(tuning, "REPLY_DELAY_US", 0) / 1e6
DROP_EVERY = getattr(tuning, "DROP_EVERY", 0)
DROPPED_HELD_S = 0.5  # a dropped query is finished only after this (the caller times out first)
MAX_LEG_GAP = 0.8  # metres: two legs further apart than this are not one person


def pair_score(a: dict[str, float], b: dict[str, float], work: int = WORK_PER_PAIR) -> float:
    """How likely two legs belong to one person: a deliberately CPU-heavy iterative fit of
    ``work`` steps."""
    dx, dy = a["x"] - b["x"], a["y"] - b["y"]
    gap = math.hypot(dx, dy)
    score = 0.0
    for step in range(work):
        phase = (step + 1) * 0.001
        score += math.exp(-((gap - 0.35 + phase) ** 2)) * math.cos(phase * gap)
    return score / work


class ObjectBuilder:
    """Fuses legs and the latest robot pose into person hypotheses."""

    def __init__(self, publisher: zenoh.Publisher, work_per_pair: int = WORK_PER_PAIR) -> None:
        self._publisher = publisher
        self._work = work_per_pair
        self._pose = (0.0, 0.0, 0.0)
        self._lock = threading.Lock()
        self.running = threading.Event()  # cleared by a "stall" fault
        self.running.set()

    def on_pose(self, data: bytes) -> None:
        pose = json.loads(data)
        with self._lock:
            self._pose = (float(pose["x"]), float(pose["y"]), float(pose["theta"]))

    def fuse(self, data: bytes) -> str:
        """The persons in a leg message, as the JSON text published or replied."""
        message = json.loads(data)
        legs: list[dict[str, float]] = message["legs"]
        with self._lock:
            px, py, theta = self._pose
        persons: list[dict[str, Any]] = []
        for i, a in enumerate(legs):
            for b in legs[i + 1 :]:
                score = pair_score(a, b, self._work)
                if math.hypot(a["x"] - b["x"], a["y"] - b["y"]) <= MAX_LEG_GAP:
                    persons.append(_person(a, b, score, px, py, theta))
        return json.dumps({"stamp": message.get("stamp"), "persons": persons})

    def on_legs(self, data: bytes) -> None:
        self.running.wait()
        self._publisher.put(self.fuse(data), encoding="application/json")


class Locator:
    """Answers ``objectbuilder/locate`` queries (on zenoh's callback thread, one at a time)."""

    def __init__(self, builder: ObjectBuilder, key: str) -> None:
        self._builder = builder
        self._key = key
        self._received = 0

    def on_query(self, query: zenoh.Query) -> None:
        self._received += 1
        if DROP_EVERY and self._received % DROP_EVERY == 0:
            threading.Timer(DROPPED_HELD_S, _finish, args=(query,)).start()
            return
        with query:  # a query must be finished, or the caller waits for its timeout
            try:
                data = query.payload.to_bytes() if query.payload is not None else b""
                persons = self._builder.fuse(data)
            except (ValueError, KeyError, TypeError) as exc:
                query.reply_err(f"malformed leg message: {exc!r}")
                return
            if REPLY_DELAY_S:
                time.sleep(REPLY_DELAY_S)
            query.reply(self._key, persons, encoding="application/json")


def _finish(query: zenoh.Query) -> None:
    with query:
        pass


def _person(
    a: dict[str, float], b: dict[str, float], score: float, px: float, py: float, theta: float
) -> dict[str, float]:
    mx, my = (a["x"] + b["x"]) / 2, (a["y"] + b["y"]) / 2
    cos, sin = math.cos(theta), math.sin(theta)
    return {"x": px + cos * mx - sin * my, "y": py + sin * mx + cos * my, "score": score}


FAULTS = ("busy", "leak", "stall")
LEAK_BYTES, LEAK_EVERY_S = 256 * 1024, 0.05
#: the busy thread's work, over and over: a key derivation of this many rounds (about 50 ms),
#: for which hashlib lets go of the GIL, so the thread spins as a stuck loop in a component's
#: native code would, a core's worth whatever the workers do (1.9 cores beside a thread spinning
#: in Python). Spinning in Python itself, it took only the GIL's time the workers left: +28 % of
#: a core on a VM where they held it most of the time, under a threshold of 24.5 for 12 s
#: (2026-11-29)
SPIN_ROUNDS = 100_000


def inject_faults(path: str, builder: ObjectBuilder, stop: threading.Event) -> None:
    """Acts out the fault that ``path`` names while the file exists (see the module's doc)."""
    leaked: list[bytearray] = []
    while not stop.is_set():
        try:
            with open(path, encoding="utf-8") as file:
                fault = file.read().strip()
        except FileNotFoundError:
            fault = ""
        if fault == "stall":
            builder.running.clear()
        else:
            builder.running.set()
        end = time.monotonic() + LEAK_EVERY_S
        if fault == "busy":
            while time.monotonic() < end:
                hashlib.pbkdf2_hmac("sha256", b"busy", b"salt", SPIN_ROUNDS)
        else:
            if fault == "leak":
                leaked.append(bytearray(b"\x01" * LEAK_BYTES))  # touched: resident, not reserved
            stop.wait(LEAK_EVERY_S)
    builder.running.set()


def _guarded(work: Any, data: bytes) -> None:
    try:
        work(data)
    except (ValueError, KeyError, TypeError) as exc:  # a bad message must not kill the component
        print(f"objectbuilder: dropped a malformed message: {exc!r}", file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2, help="worker threads for leg messages")
    parser.add_argument(
        "--prefix",
        default="objectbuilder",
        help="key prefix of its inputs and output (several can run side by side)",
    )
    parser.add_argument(
        "--faults", metavar="FILE", help=f"inject the fault FILE names ({', '.join(FAULTS)})"
    )
    parser.add_argument(
        "--work-per-pair",
        type=int,
        default=WORK_PER_PAIR,
        help="steps of the fit per pair of legs (default: tuning.WORK_PER_PAIR, which revisions "
        "change; the resource-model evaluation sets its own so that its sweep never saturates "
        "a core)",
    )
    args = parser.parse_args(argv)
    if args.work_per_pair < 1:
        parser.error("--work-per-pair must be at least 1")
    stop = threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        # set from a thread of its own: a handler interrupting stop.wait() while it holds the
        # event's lock would wait for that lock for ever
        signal.signal(signum, lambda *_: threading.Thread(target=stop.set).start())
    legs_pool = ThreadPoolExecutor(args.threads, thread_name_prefix="legs")
    pose_pool = ThreadPoolExecutor(1, thread_name_prefix="pose")
    with zenoh.open(zenoh.Config.from_env()) as session:
        keys = {
            key: key.replace("objectbuilder", args.prefix, 1)
            for key in (LEGS_KEY, POSE_KEY, PERSONS_KEY, LOCATE_KEY)
        }
        builder = ObjectBuilder(session.declare_publisher(keys[PERSONS_KEY]), args.work_per_pair)
        session.declare_subscriber(
            keys[LEGS_KEY],
            lambda s: legs_pool.submit(_guarded, builder.on_legs, s.payload.to_bytes()),
        )
        session.declare_subscriber(
            keys[POSE_KEY],
            lambda s: pose_pool.submit(_guarded, builder.on_pose, s.payload.to_bytes()),
        )
        locator = Locator(builder, keys[LOCATE_KEY])
        session.declare_queryable(keys[LOCATE_KEY], locator.on_query)
        if args.faults:
            threading.Thread(
                target=inject_faults, args=(args.faults, builder, stop), daemon=True
            ).start()
        print(
            f"objectbuilder ready (threads={args.threads}, work per pair={args.work_per_pair})",
            flush=True,
        )
        while not stop.wait(0.2):  # a timed wait keeps signal handlers responsive
            pass
    builder.running.set()
    legs_pool.shutdown(wait=True, cancel_futures=True)
    pose_pool.shutdown(wait=True, cancel_futures=True)
    print("objectbuilder stopped", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
