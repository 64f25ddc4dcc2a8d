"""A component's detection configuration: which methods, against which baseline, at what thresholds.

Pure data and validation (no database): the worker reads it from the ``detection_config`` table,
the API validates what an admin sends with `DetectionConfig.parse`. Errors name the field.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from redline.detect.baseline import DEFAULT_WINDOW
from redline.detect.evaluate import DEFAULT_METHOD
from redline.detect.executions import BuildShift, ExecutionShift
from redline.detect.foo import FooRules
from redline.detect.methods import Detector, KolmogorovSmirnov, MannWhitney, WelchT
from redline.detect.robust import MedianShift
from redline.detect.shang import ShangRegression

#: Methods the worker can run per series on every ingest. Foo and Shang run in their
#: one-counter form (a series is one counter); E-divisive needs a whole history, not one build.
WORKER_DETECTORS: dict[str, Callable[..., Detector]] = {
    "execution_shift": ExecutionShift,
    "build_shift": BuildShift,
    "ks": KolmogorovSmirnov,
    "mann_whitney": MannWhitney,
    "welch_t": WelchT,
    "median_shift": MedianShift,
    "foo": FooRules,
    "shang": ShangRegression,
}
#: The evaluated default (docs/detection.md) and KS, which the trend charts draw.
DEFAULT_METHODS: tuple[str, ...] = tuple(dict.fromkeys((DEFAULT_METHOD, "ks")))
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
    """

    methods: tuple[str, ...] = DEFAULT_METHODS
    baseline: str = "recent"
    window: int = DEFAULT_WINDOW
    pinned: str | None = None
    thresholds: Mapping[str, Mapping[str, float]] = field(default_factory=dict)

    @classmethod
    def parse(cls, data: Mapping[str, Any] | None) -> DetectionConfig:
        """A validated configuration from plain data; missing fields take the defaults."""
        data = dict(data or {})
        unknown = set(data) - {"methods", "baseline", "window", "pinned", "thresholds"}
        if unknown:
            raise ConfigError(f"unknown field(s) {sorted(unknown)}")
        thresholds = data.get("thresholds") or {}
        config = cls(
            methods=tuple(data.get("methods") or DEFAULT_METHODS),
            baseline=str(data.get("baseline", "recent")),
            window=int(data.get("window", DEFAULT_WINDOW)),
            pinned=data.get("pinned"),
            thresholds={str(k): dict(v) for k, v in thresholds.items()},
        )
        config.validate()
        return config

    def validate(self) -> None:
        for name in self.methods:
            if name not in WORKER_DETECTORS:
                raise ConfigError(
                    f"methods: unknown method {name!r}; known: {', '.join(WORKER_DETECTORS)}"
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
            allowed = list(inspect.signature(WORKER_DETECTORS[name].__init__).parameters)[1:]
            for key in params:
                if key not in allowed:
                    raise ConfigError(
                        f"thresholds.{name}: unknown parameter {key!r}; known: {', '.join(allowed)}"
                    )

    def detectors(self) -> list[Detector]:
        """One detector per configured method, with its thresholds."""
        return [WORKER_DETECTORS[name](**self.thresholds.get(name, {})) for name in self.methods]

    def as_dict(self) -> dict[str, Any]:
        return {
            "methods": list(self.methods),
            "baseline": self.baseline,
            "window": self.window,
            "pinned": self.pinned,
            "thresholds": {k: dict(v) for k, v in self.thresholds.items()},
        }
