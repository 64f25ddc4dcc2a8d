"""Whether the component took part in the run at all: the rule behind the status ``no_traffic``.

A component that never joins the run's zenoh network (say it ignores ``ZENOH_CONFIG``) still
runs, idles at 0 % CPU and exits cleanly, and its recording would look like a fine result. So a
run whose every test ran is recorded as ``no_traffic``, with a ``warning`` naming each reason,
when either holds:

- **no process of the suite joined the run's zenoh network**: the run's router saw no session
  but Redline's own (the driver, the recorder and the monitor, whose ids Redline chooses), from
  its start to the end of the tests. Every [[component]] and [[fixture]] counts, in any mode.
- **no query was answered**: the measured (not warm-up) phases sent queries (`Query`), and not
  one of them got a reply, not even an error reply (timeouts and "no queryable" alike).

A component that joins and serves but publishes nothing (a sink) is not flagged; a run with no
query in its measured phases is judged by the first rule alone.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from redline.testing import Phase


@dataclass
class TrafficCheck:
    """Collects what the rule needs while the tests run; `warnings` applies it at the end."""

    own_sessions: set[str] = field(default_factory=set)
    queries: int = 0
    answered: int = 0

    def observe(self, phase: Phase, reports: Iterable[dict[str, Any]]) -> None:
        """A segment's driver reports (what `Context.flush_metrics` published)."""
        if phase.warmup:
            return
        for report in reports:
            if report.get("action") == "Query":
                self.queries += int(report.get("queries", 0))
                self.answered += int(report.get("count", 0)) + int(report.get("errors", 0))

    def warnings(self, sessions_seen: set[str]) -> list[str]:
        """Why the run shows no traffic of the component; empty when it took part."""
        found = []
        if not sessions_seen - self.own_sessions:
            found.append(
                "no process of the suite joined the run's zenoh network (does the "
                "component open zenoh with ZENOH_CONFIG or {zenoh_config}?)"
            )
        if self.queries and not self.answered:
            found.append(f"none of the {self.queries} queries of the measured phases was answered")
        return found
