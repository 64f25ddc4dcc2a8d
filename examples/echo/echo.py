"""echo: a minimal service component with a zenoh queryable and a relay.

- Queryable ``echo/ping``: replies with the query's payload (on ``echo/ping``), after
  ``--work`` iterations of busy work per KiB of payload (to give its CPU something to show).
- Subscriber ``echo/in``: republishes every sample on ``echo/out`` with the same payload and
  attachment (so a test's sequence numbers come back, and `Listen` can count losses).

Opens zenoh with ``zenoh.Config.from_env()`` (``ZENOH_CONFIG``), prints ``echo ready`` once its
queryable and subscriber are declared, and exits cleanly on SIGTERM or SIGINT.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

import zenoh

PING_KEY = "echo/ping"
IN_KEY = "echo/in"
OUT_KEY = "echo/out"


def busy(work: int, size: int) -> int:
    """Deliberate CPU work proportional to the payload size."""
    total = 0
    for step in range(work * max(1, size // 1024)):
        total += step * step % 7
    return total


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=int, default=200, help="busy steps per KiB of query")
    args = parser.parse_args(argv)
    stop = threading.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        # set from a thread of its own: a handler interrupting stop.wait() while it holds the
        # event's lock would wait for that lock for ever
        signal.signal(signum, lambda *_: threading.Thread(target=stop.set).start())
    with zenoh.open(zenoh.Config.from_env()) as session:
        publisher = session.declare_publisher(OUT_KEY)

        def answer(query: zenoh.Query) -> None:
            with query:  # a query must be finished, or the caller waits for its timeout
                data = query.payload.to_bytes() if query.payload is not None else b""
                busy(args.work, len(data))
                query.reply(PING_KEY, data)

        def relay(sample: zenoh.Sample) -> None:
            publisher.put(sample.payload, attachment=sample.attachment)

        session.declare_queryable(PING_KEY, answer)
        session.declare_subscriber(IN_KEY, relay)
        print(f"echo ready (work={args.work})", flush=True)
        while not stop.wait(0.2):  # a timed wait keeps signal handlers responsive
            pass
    print("echo stopped", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
