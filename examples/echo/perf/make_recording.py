"""Write ``sensors.mcap``, the small recording `test_echo.py` replays (run it to regenerate).

Two seconds of a fake robot: ``robot/scan`` at 20 Hz (1 KiB each) and ``robot/odom`` at 50 Hz,
in Redline's recording format, as `redline run` would have recorded them.
"""

from __future__ import annotations

import json
from pathlib import Path

from redline.recording import RecordingWriter

HERE = Path(__file__).resolve().parent


def main() -> None:
    start = 1_700_000_000_000_000_000
    with RecordingWriter(HERE / "sensors.mcap", library="echo example") as writer:
        for tick in range(100):  # 50 Hz for 2 s
            t_ns = start + tick * 20_000_000
            odom = {"x": tick * 0.01, "y": 0.0, "theta": 0.0}
            writer.write(
                "robot/odom", json.dumps(odom).encode(), encoding="application/json", t_ns=t_ns
            )
            if tick % 2 == 0:
                writer.write(
                    "robot/scan",
                    bytes([tick % 256]) * 1024,
                    encoding="application/octet-stream",
                    t_ns=t_ns,
                )
        writer.metadata("redline.run", {"component": "robot", "note": "synthetic example"})


if __name__ == "__main__":
    main()
