"""objectbuilder: a data-fusion mock after Wienke & Wrede's example component.

Subscribes to leg detections (``objectbuilder/legs``, JSON ``{"stamp", "legs": [{"x", "y"}]}``) and
robot poses (``objectbuilder/pose``, JSON ``{"x", "y", "theta"}``), pairs up legs into person
hypotheses in world coordinates, and publishes them on ``objectbuilder/persons``. The work per leg
message grows with the square of the number of legs (every pair is scored, `tuning.WORK_PER_PAIR`
steps each). Leg messages are processed by a thread pool (``--threads``), poses by one thread.

Opens zenoh with ``zenoh.Config.from_env()`` (``ZENOH_CONFIG``), prints ``objectbuilder ready``
once its subscribers and publisher are declared, and exits cleanly on SIGTERM or SIGINT.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import zenoh
from tuning import WORK_PER_PAIR

LEGS_KEY = "objectbuilder/legs"
POSE_KEY = "objectbuilder/pose"
PERSONS_KEY = "objectbuilder/persons"
MAX_LEG_GAP = 0.8  # metres: two legs further apart than this are not one person


def pair_score(a: dict[str, float], b: dict[str, float]) -> float:
    """How likely two legs belong to one person: a deliberately CPU-heavy iterative fit."""
    dx, dy = a["x"] - b["x"], a["y"] - b["y"]
    gap = math.hypot(dx, dy)
    score = 0.0
    for step in range(WORK_PER_PAIR):
        phase = (step + 1) * 0.001
        score += math.exp(-((gap - 0.35 + phase) ** 2)) * math.cos(phase * gap)
    return score / WORK_PER_PAIR


class ObjectBuilder:
    """Fuses legs and the latest robot pose into person hypotheses."""

    def __init__(self, publisher: zenoh.Publisher) -> None:
        self._publisher = publisher
        self._pose = (0.0, 0.0, 0.0)
        self._lock = threading.Lock()

    def on_pose(self, data: bytes) -> None:
        pose = json.loads(data)
        with self._lock:
            self._pose = (float(pose["x"]), float(pose["y"]), float(pose["theta"]))

    def on_legs(self, data: bytes) -> None:
        message = json.loads(data)
        legs: list[dict[str, float]] = message["legs"]
        with self._lock:
            px, py, theta = self._pose
        persons: list[dict[str, Any]] = []
        for i, a in enumerate(legs):
            for b in legs[i + 1 :]:
                score = pair_score(a, b)
                if math.hypot(a["x"] - b["x"], a["y"] - b["y"]) <= MAX_LEG_GAP:
                    persons.append(_person(a, b, score, px, py, theta))
        reply = {"stamp": message.get("stamp"), "persons": persons}
        self._publisher.put(json.dumps(reply), encoding="application/json")


def _person(
    a: dict[str, float], b: dict[str, float], score: float, px: float, py: float, theta: float
) -> dict[str, float]:
    mx, my = (a["x"] + b["x"]) / 2, (a["y"] + b["y"]) / 2
    cos, sin = math.cos(theta), math.sin(theta)
    return {"x": px + cos * mx - sin * my, "y": py + sin * mx + cos * my, "score": score}


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
    args = parser.parse_args(argv)
    stop = threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, lambda *_: stop.set())
    legs_pool = ThreadPoolExecutor(args.threads, thread_name_prefix="legs")
    pose_pool = ThreadPoolExecutor(1, thread_name_prefix="pose")
    with zenoh.open(zenoh.Config.from_env()) as session:
        keys = {
            key: key.replace("objectbuilder", args.prefix, 1)
            for key in (LEGS_KEY, POSE_KEY, PERSONS_KEY)
        }
        builder = ObjectBuilder(session.declare_publisher(keys[PERSONS_KEY]))
        session.declare_subscriber(
            keys[LEGS_KEY],
            lambda s: legs_pool.submit(_guarded, builder.on_legs, s.payload.to_bytes()),
        )
        session.declare_subscriber(
            keys[POSE_KEY],
            lambda s: pose_pool.submit(_guarded, builder.on_pose, s.payload.to_bytes()),
        )
        print(
            f"objectbuilder ready (threads={args.threads}, work per pair={WORK_PER_PAIR})",
            flush=True,
        )
        while not stop.wait(0.2):  # a timed wait keeps signal handlers responsive
            pass
    legs_pool.shutdown(wait=True, cancel_futures=True)
    pose_pool.shutdown(wait=True, cancel_futures=True)
    print("objectbuilder stopped", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
