"""Performance tests of the echo service: queries, a relayed stream, and a replayed recording.

- ``ping``: queries at a fixed rate with payloads of 64 B or 4 KiB (round trips and timeouts
  are reported per parameter set), after a warm-up.
- ``relay``: a JSON stream with sequence numbers published on ``echo/in`` while `Listen` counts
  what comes back on ``echo/out`` and how much was lost.
- ``replay``: the laser scans of a recorded robot (``sensors.mcap``) replayed into the relay at
  1x and 4x speed, with ``robot/scan`` remapped onto ``echo/in``.
"""

from __future__ import annotations

from pathlib import Path

from redline.testing import (
    Cartesian,
    FixedRate,
    Listen,
    Message,
    Param,
    Phase,
    Publish,
    Query,
    Repeated,
    Replay,
    Table,
    TestCase,
)

RECORDING = Path(__file__).resolve().parent / "sensors.mcap"

PING = Query("echo/ping", Message.raw(Param("size")), timeout=1.0)

ping = TestCase(
    "ping",
    phases=[
        Phase("warmup", FixedRate(50, 0.3, PING), warmup=True),
        Phase("steady", FixedRate(Param("rate"), 1.0, PING)),
    ],
    params=Cartesian(
        size=[64, 4096], rate=[50, 200], where=lambda p: p["size"] < 4096 or p["rate"] <= 50
    ),  # no 4 KiB at 200 Hz
)

READING = Message.json({"ranges": Repeated(lambda i: 1.0 + i * 0.01, Param("points"))})

relay = TestCase(
    "relay",
    phases=[
        Phase(
            "stream",
            Listen(
                "echo/out",
                FixedRate(Param("rate"), 1.0, Publish("echo/in", READING, sequence=True)),
            ),
        )
    ],
    params=Table(["points", "rate"], [(10, 100), (500, 100)]),
)

replay = TestCase(
    "replay",
    phases=[
        Phase(
            "scans",
            Listen(
                "echo/out",
                Replay(
                    RECORDING,
                    speed=Param("speed"),
                    keys=["robot/scan"],
                    remap={"robot/scan": "echo/in"},
                ),
            ),
        )
    ],
    params=Cartesian(speed=[1.0, 4.0]),
)
