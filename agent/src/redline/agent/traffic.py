"""Whether the component took part in the run at all: the rule behind the status ``no_traffic``.

A component that never joins the run's zenoh network (say it ignores ``ZENOH_CONFIG``) still
runs, idles at 0 % CPU and exits cleanly, and its recording would look like a fine result. So a
run whose every test ran is recorded as ``no_traffic``, with a ``warning`` naming each reason,
when any of these holds:

- **no process of the suite joined the run's zenoh network**: the run's router saw no session
  but Redline's own (the driver, the recorder and the monitor, whose ids Redline chooses), from
  its start to the end of the tests. Every [[component]] and [[fixture]] counts, in any mode.
- **no query was answered**: the measured (not warm-up) phases sent queries (`Query`), and not
  one of them got a reply, not even an error reply (timeouts and "no queryable" alike).
- **nothing the tests waited for arrived**: the measured phases waited for samples (`WaitFor`,
  `Listen`), and not one came.
- **the component published nothing and heard nothing**: the measured phases neither queried
  nor waited, so the suite does not say what the component gives back; then the processes of
  the suite put no sample at all on the run's network during the whole run (the recorder saw
  none on a key the driver never published on), and none of them subscribed to a key the tests
  published on.

A sink (it subscribes to what the tests publish, and publishes nothing) is not flagged: what it
does with the samples cannot be seen on the network.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import zenoh
from redline.testing import Phase


@dataclass(frozen=True)
class NetworkView:
    """What the run's network saw of the suite's processes by the end of the tests."""

    #: samples the recorder recorded per key (Redline's own ``@redline/**`` left out)
    recorded: Mapping[str, int]
    #: the keys the driver published on (its samples, not the component's)
    driver_keys: frozenset[str]
    #: key expressions the suite's processes (not Redline's own) subscribed to
    subscriptions: frozenset[str]

    def component_samples(self) -> int:
        """Samples recorded on keys the driver never published on: the suite's processes'."""
        return sum(n for key, n in self.recorded.items() if key not in self.driver_keys)

    def heard(self) -> bool:
        """Whether a process of the suite subscribed to a key the driver published on."""
        return any(
            zenoh.KeyExpr(subscribed).intersects(zenoh.KeyExpr(key))
            for subscribed in self.subscriptions
            for key in self.driver_keys
        )


def _listed(keys: set[str], most: int = 3) -> str:
    shown = sorted(keys)
    return ", ".join(shown[:most]) + (f" and {len(shown) - most} more" if len(shown) > most else "")


@dataclass
class TrafficCheck:
    """Collects what the rule needs while the tests run; `warnings` applies it at the end."""

    own_sessions: set[str] = field(default_factory=set)
    queries: int = 0
    answered: int = 0
    waits: int = 0  # WaitFor runs and Listen actions of the measured phases
    arrived: int = 0  # the samples they got
    waited_keys: set[str] = field(default_factory=set)

    def observe(self, phase: Phase, reports: Iterable[dict[str, Any]]) -> None:
        """A segment's driver reports (what `Context.flush_metrics` published)."""
        if phase.warmup:
            return
        for report in reports:
            action = report.get("action")
            if action == "Query":
                self.queries += int(report.get("queries", 0))
                self.answered += int(report.get("count", 0)) + int(report.get("errors", 0))
            elif action in ("WaitFor", "Listen"):
                self.waits += int(report.get("waits", 0)) if action == "WaitFor" else 1
                self.arrived += int(report.get("count" if action == "WaitFor" else "received", 0))
                self.waited_keys.add(str(report.get("key", "?")))

    def warnings(self, sessions_seen: set[str], network: NetworkView | None = None) -> list[str]:
        """Why the run shows no traffic of the component; empty when it took part.
        ``network``: what the recorder and the router saw (without it, the last rule is not
        applied)."""
        found = []
        if not sessions_seen - self.own_sessions:
            found.append(
                "no process of the suite joined the run's zenoh network (does the "
                "component open zenoh with ZENOH_CONFIG or {zenoh_config}?)"
            )
        if self.queries and not self.answered:
            found.append(f"none of the {self.queries} queries of the measured phases was answered")
        if self.waits and not self.arrived:
            found.append(
                f"no sample arrived on {_listed(self.waited_keys)}, which the measured phases "
                f"waited for {self.waits} time(s)"
            )
        if found or self.queries or self.waits or network is None:
            return found
        if not network.component_samples() and not network.heard():
            keys = set(network.driver_keys)
            deaf = f", nor subscribed to what the tests published ({_listed(keys)})" if keys else ""
            found.append(f"the component published nothing on the run's network{deaf}")
        return found
