"""The test SDK's speed, as ratios against references measured in the same run.

1. FixedRate at 1 kHz and 10 kHz with a no-op child: achieved rate / requested, and p99
   lateness against a loop that sleeps to the same absolute deadlines without spinning.
2. Publish through the SDK (``LimitedTime(Loop(Publish(...)))``) against a bare zenoh
   ``put`` loop on a declared publisher, 8 B and 1 KiB payloads, with a subscriber in another
   process on the same isolated network: the median over interleaved pairs of SDK rate / bare
   rate, by wall clock and per CPU second of the publishing thread (see `publish`).

Run: .venv/bin/python benchmarks/bench_sdk.py   (prints figures; not a test)
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import time

from redline.agent.network import RunNetwork, open_client
from redline.testing import Context, FixedRate, LimitedTime, Link, Loop, Publish, Static
from redline.testing.metrics import quantile

SECONDS = 3.0
PAIRS, PAIR_SECONDS = 21, 0.3
SUBSCRIBER = """\
import json, sys, threading, zenoh
from redline.agent.network import config_from_dict
count = [0]
with zenoh.open(config_from_dict(json.loads(sys.argv[1]))) as session:
    session.declare_subscriber("bench/**", lambda s: count.__setitem__(0, count[0] + 1))
    print("ready", flush=True)
    sys.stdin.readline()
print(count[0], flush=True)
"""


def sleep_loop(rate: float, seconds: float) -> tuple[float, int]:
    """The reference: ``time.sleep`` to each absolute deadline, no spin; (rate, p99 late ns)."""
    period_ns, start, late = 1e9 / rate, time.perf_counter_ns(), []
    deadline = start
    while deadline < start + seconds * 1e9:
        time.sleep(max(0, deadline - time.perf_counter_ns()) / 1e9)
        late.append(time.perf_counter_ns() - deadline)
        deadline = start + int(len(late) * period_ns)
    elapsed = (time.perf_counter_ns() - start) / 1e9
    late.sort()
    return len(late) / elapsed, quantile(late, 0.99)


def fixed_rate(rate: float) -> None:
    ctx = Context({})
    FixedRate(rate, SECONDS, Static(None)).run(ctx)
    report = ctx.reports[-1]
    ref_rate, ref_p99 = sleep_loop(rate, SECONDS)
    print(
        f"FixedRate {rate:>6.0f} Hz: achieved/requested {report['rate_achieved'] / rate:.4f} "
        f"(sleep loop {ref_rate / rate:.4f}); p99 lateness {report['lateness_p99_us']:.1f} us "
        f"= {report['lateness_p99_us'] * 1e3 / max(ref_p99, 1):.3f} x the sleep loop's "
        f"{ref_p99 / 1e3:.1f} us"
    )


Rates = tuple[float, float]  # samples per wall-clock second, per CPU second of this thread


def bare_rate(publisher, payload: bytes, seconds: float) -> Rates:  # type: ignore[no-untyped-def]
    sent, began, cpu = 0, time.perf_counter(), time.thread_time()
    end = began + seconds
    while time.perf_counter() < end:
        for _ in range(100):
            publisher.put(payload)
        sent += 100
    return sent / (time.perf_counter() - began), sent / (time.thread_time() - cpu)


def sdk_rate(ctx: Context, payload: bytes, seconds: float) -> Rates:
    began, cpu = time.perf_counter(), time.thread_time()
    sent = float(LimitedTime(seconds, Loop(Publish("bench/sdk", payload))).run(ctx))
    return sent / (time.perf_counter() - began), sent / (time.thread_time() - cpu)


def _spread(ratios: list[float]) -> str:
    q1, median, q3 = statistics.quantiles(ratios, n=4)
    return f"{statistics.median(ratios):.3f} (middle half {q1:.3f}-{q3:.3f})"


def publish(network: RunNetwork, size: int, pairs: int = PAIRS) -> None:
    """Bare and SDK loops in pairs of short runs, the order alternating from pair to pair (the
    host is shared and noisy: a slow spell then hits both sides of a pair). Figures: the median
    of the per-pair ratios of wall-clock rates, and of rates per CPU second of the publishing
    thread (what the SDK's own path costs, immune to time spent descheduled)."""
    payload = b"x" * size
    with open_client(network.client_settings()) as session:
        link = Link(session)
        ctx = Context({}, link=link)
        bare_rate(link.publisher("bench/bare"), payload, 0.5)  # warm-up: declarations settle
        sdk_rate(ctx, payload, 0.5)
        wall, cpu, sdk_rates = [], [], []
        for index in range(pairs):
            runs = {
                "bare": lambda: bare_rate(link.publisher("bench/bare"), payload, PAIR_SECONDS),
                "sdk": lambda: sdk_rate(ctx, payload, PAIR_SECONDS),
            }
            order = ("bare", "sdk") if index % 2 == 0 else ("sdk", "bare")
            rates = {name: runs[name]() for name in order}
            wall.append(rates["sdk"][0] / rates["bare"][0])
            cpu.append(rates["sdk"][1] / rates["bare"][1])
            sdk_rates.append(rates["sdk"][0])
        link.close()
    print(
        f"Publish {size:>5} B: SDK/bare median ratio, wall clock {_spread(wall)}; per CPU "
        f"second {_spread(cpu)}; {pairs} interleaved pairs of {PAIR_SECONDS:g} s; SDK median "
        f"{statistics.median(sdk_rates):,.0f}/s"
    )


def main() -> None:
    for rate in (1000.0, 10000.0):
        fixed_rate(rate)
    with RunNetwork() as network:
        listener = subprocess.Popen(
            [sys.executable, "-c", SUBSCRIBER, json.dumps(network.client_settings())],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert listener.stdout is not None and listener.stdin is not None
        listener.stdout.readline()
        for size in (8, 1024):
            publish(network, size)
        listener.stdin.write("\n")
        listener.stdin.close()
        print(f"(the subscriber process received {listener.stdout.readline().strip()} samples)")
        listener.wait()


if __name__ == "__main__":
    main()
