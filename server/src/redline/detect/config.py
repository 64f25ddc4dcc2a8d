"""A component's detection configuration: which methods, against which baseline, at what thresholds.

Pure data and validation (no database): the worker reads it from the ``detection_config`` table,
the API validates what an admin sends with `DetectionConfig.parse`. Errors name the field.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from redline.detect.baseline import DEFAULT_WINDOW
from redline.detect.counters import CONTEXT_COUNTERS
from redline.detect.methods import Detector
from redline.detect.registry import DEFAULT_METHOD, DETECTORS

#: The method whose verdicts the trend charts draw and ``/changes`` lists.
CHARTED_METHOD = "ks"
#: The evaluated default (docs/detection.md) and the charted method.
DEFAULT_METHODS: tuple[str, ...] = tuple(dict.fromkeys((DEFAULT_METHOD, CHARTED_METHOD)))
BASELINES = ("recent", "previous", "window", "pinned")
MAX_WINDOW = 50


class ConfigError(ValueError):
    """A configuration that cannot be used; the message names the field at fault."""


@dataclass(frozen=True)
class DetectionConfig:
    """``baseline``: ``recent`` (the newest revisions with the series, pooled until the method
    has enough values, at most ``window``, restarting at its newest flagged change;
    `redline.detect.baseline`), ``previous`` (the last revision with the series), ``window``
    (the last ``window`` such revisions, pooled) or ``pinned`` (the revision titled ``pinned``).
    ``thresholds``: per method, keyword arguments of its detector (``{"ks": {"alpha": 0.001}}``).
    ``context_counters``: counters recorded and charted but not judged (by default the
    user/system split of CPU, whose total is judged; `redline.detect.counters`).
    """

    methods: tuple[str, ...] = DEFAULT_METHODS
    baseline: str = "recent"
    window: int = DEFAULT_WINDOW
    pinned: str | None = None
    thresholds: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    context_counters: tuple[str, ...] = CONTEXT_COUNTERS

    @classmethod
    def parse(cls, data: Mapping[str, Any] | None) -> DetectionConfig:
        """A validated configuration from plain data; missing fields take the defaults."""
        data = dict(data or {})
        unknown = set(data) - {
            "methods",
            "baseline",
            "window",
            "pinned",
            "thresholds",
            "context_counters",
        }
        if unknown:
            raise ConfigError(f"unknown field(s) {sorted(unknown)}")
        thresholds = data.get("thresholds") or {}
        config = cls(
            methods=tuple(data.get("methods") or DEFAULT_METHODS),
            baseline=str(data.get("baseline", "recent")),
            window=int(data.get("window", DEFAULT_WINDOW)),
            pinned=data.get("pinned"),
            thresholds={str(k): dict(v) for k, v in thresholds.items()},
            context_counters=tuple(str(c) for c in data.get("context_counters", CONTEXT_COUNTERS)),
        )
        config.validate()
        return config

    def validate(self) -> None:
        for name in self.methods:
            if name not in DETECTORS:
                raise ConfigError(
                    f"methods: unknown method {name!r}; known: {', '.join(DETECTORS)}"
                )
        if not self.methods:
            raise ConfigError("methods: at least one method is needed")
        if self.baseline not in BASELINES:
            raise ConfigError(
                f"baseline: must be one of {', '.join(BASELINES)}, not {self.baseline!r}"
            )
        if not 1 <= self.window <= MAX_WINDOW:
            raise ConfigError(f"window: must be 1..{MAX_WINDOW}, not {self.window}")
        if self.baseline == "pinned" and not self.pinned:
            raise ConfigError("pinned: a pinned baseline needs the revision's title")
        for name, params in self.thresholds.items():
            if name not in self.methods:
                raise ConfigError(f"thresholds: {name!r} is not among the methods")
            allowed = list(inspect.signature(DETECTORS[name].__init__).parameters)[1:]
            for key in params:
                if key not in allowed:
                    raise ConfigError(
                        f"thresholds.{name}: unknown parameter {key!r}; known: {', '.join(allowed)}"
                    )

    def detectors(self) -> list[Detector]:
        """One detector per configured method, with its thresholds."""
        return [DETECTORS[name](**self.thresholds.get(name, {})) for name in self.methods]

    def as_dict(self) -> dict[str, Any]:
        return {
            "methods": list(self.methods),
            "baseline": self.baseline,
            "window": self.window,
            "pinned": self.pinned,
            "thresholds": {k: dict(v) for k, v in self.thresholds.items()},
            "context_counters": list(self.context_counters),
        }
