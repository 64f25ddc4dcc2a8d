"""A component's detection configuration: which methods, against which baseline, at what thresholds.

Pure data and validation (no database): the worker reads it from the ``detection_config`` table,
the API validates what an admin sends with `DetectionConfig.parse`. Errors name the field.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from redline.detect.baseline import DEFAULT_WINDOW
from redline.detect.confirmation import DEFAULT_CONFIRM_PAIRS, DEFAULT_CONFIRM_REVISIONS
from redline.detect.count_rate import CountRate
from redline.detect.counters import CONTEXT_COUNTERS
from redline.detect.methods import Detector
from redline.detect.registry import DEFAULT_METHOD, DETECTORS

#: The method whose verdicts the trend charts draw and ``/changes`` lists.
CHARTED_METHOD = "ks"
#: The evaluated default (docs/detection.md) and the charted method.
DEFAULT_METHODS: tuple[str, ...] = tuple(dict.fromkeys((DEFAULT_METHOD, CHARTED_METHOD)))
BASELINES = ("recent", "previous", "window", "pinned")
MAX_WINDOW = 50
MAX_CONFIRM_REVISIONS = 10
MAX_CONFIRM_PAIRS = 10


class ConfigError(ValueError):
    """A configuration that cannot be used; the message names the field at fault."""


def _integer(value: Any, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"{name}: must be a whole number, not {value!r}")
    return value


#: thresholds that are probabilities or shares: strictly between 0 and 1
_PROBABILITIES = {"alpha", "confidence_lv", "min_support", "min_confidence"}


def _check_threshold(where: str, value: Any, default: Any) -> None:
    """A threshold of the kind its default is: a text, a whole number of at least 1 (a count of
    values), or a finite number of at least 0 (a probability: between 0 and 1). A value of
    another kind was stored, and every verdict of its method then failed (a trial: an alpha of
    "high" made a fourfold CPU rise pass CI)."""
    if isinstance(default, str):
        if not isinstance(value, str):
            raise ConfigError(f"{where}: must be text, like {default!r}, not {value!r}")
        return
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(f"{where}: must be a number, like {default!r}, not {value!r}")
    if isinstance(default, int) and not isinstance(default, bool):
        if not isinstance(value, int) or value < 1:
            raise ConfigError(f"{where}: must be a whole number of at least 1, not {value!r}")
    elif where.rsplit(".", 1)[-1] in _PROBABILITIES:
        if not 0 < value < 1:
            raise ConfigError(f"{where}: must be between 0 and 1, not {value!r}")
    elif value < 0:
        raise ConfigError(f"{where}: must be 0 or more, not {value!r}")


@dataclass(frozen=True)
class DetectionConfig:
    """``baseline``: ``recent`` (the newest revisions with the series, pooled until the method
    has enough values, at most ``window``, restarting at its newest flagged change;
    `redline.detect.baseline`), ``previous`` (the last revision with the series), ``window``
    (the last ``window`` such revisions, pooled) or ``pinned`` (the revision titled ``pinned``).
    ``thresholds``: per method, keyword arguments of its detector (``{"ks": {"alpha": 0.001}}``).
    ``context_counters``: counters recorded and charted but not judged (by default the
    user/system split of CPU, whose total is judged; `redline.detect.counters`).
    ``alarm_methods``: the methods whose flagged changes for the worse become regressions (the
    others' verdicts are stored and charted); empty: the first method, by default
    ``execution_shift``, which judges executions (KS on one execution's pooled samples flagged
    unchanged code: docs/detection.md).
    ``confirm_revisions``: later revisions a flagged change must hold over before its
    regression is confirmed (`redline.detect.confirmation`; 0: confirmed when flagged).
    ``confirm_pairs``: when a revision's change is flagged, run it and its baseline revision
    again this many times each, interleaved on one host, and judge the pairs
    (`redline.worker.confirm_runs`; 0: off, the history confirms; `DEFAULT_CONFIRM_PAIRS`).
    """

    methods: tuple[str, ...] = DEFAULT_METHODS
    baseline: str = "recent"
    window: int = DEFAULT_WINDOW
    pinned: str | None = None
    thresholds: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    context_counters: tuple[str, ...] = CONTEXT_COUNTERS
    confirm_revisions: int = DEFAULT_CONFIRM_REVISIONS
    alarm_methods: tuple[str, ...] = ()
    confirm_pairs: int = DEFAULT_CONFIRM_PAIRS

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
            "confirm_revisions",
            "alarm_methods",
            "confirm_pairs",
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
            alarm_methods=tuple(str(m) for m in data.get("alarm_methods") or ()),
            confirm_pairs=_integer(
                data.get("confirm_pairs", DEFAULT_CONFIRM_PAIRS), "confirm_pairs"
            ),
            confirm_revisions=_integer(
                data.get("confirm_revisions", DEFAULT_CONFIRM_REVISIONS), "confirm_revisions"
            ),
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
        for name in self.alarm_methods:
            if name not in self.methods:
                raise ConfigError(f"alarm_methods: {name!r} is not among the methods")
        if not 0 <= self.confirm_pairs <= MAX_CONFIRM_PAIRS:
            raise ConfigError(
                f"confirm_pairs: must be 0..{MAX_CONFIRM_PAIRS}, not {self.confirm_pairs}"
            )
        if not 0 <= self.confirm_revisions <= MAX_CONFIRM_REVISIONS:
            raise ConfigError(
                f"confirm_revisions: must be 0..{MAX_CONFIRM_REVISIONS}, "
                f"not {self.confirm_revisions}"
            )
        if self.baseline == "pinned" and not self.pinned:
            raise ConfigError("pinned: a pinned baseline needs the revision's title")
        for name, params in self.thresholds.items():
            if name not in self.methods:
                raise ConfigError(f"thresholds: {name!r} is not among the methods")
            allowed = _parameters(name)
            for key, value in params.items():
                if key not in allowed:
                    raise ConfigError(
                        f"thresholds.{name}: unknown parameter {key!r}; known: {', '.join(allowed)}"
                    )
                _check_threshold(f"thresholds.{name}.{key}", value, allowed[key])

    @property
    def confirms(self) -> bool:
        """Whether re-runs confirm a flagged change before it is a regression or fails CI:
        then methods judge at their confirmed bar (`Detector.confirmed`). Not the later
        revisions alone: CI fails on a change still suspected, before they come."""
        return self.confirm_pairs > 0

    def detector(self, name: str) -> Detector:
        """The configured method ``name`` with its thresholds, as it judges under this
        configuration. A component that sets ``threshold`` and not ``confirmed_threshold`` is
        judged at its ``threshold`` whether or not flags are confirmed."""
        params = dict(self.thresholds.get(name, {}))
        if "threshold" in params and "confirmed_threshold" in _parameters(name):
            params.setdefault("confirmed_threshold", params["threshold"])
        detector = DETECTORS[name](**params)
        return detector.confirmed() if self.confirms else detector

    def detectors(self) -> list[Detector]:
        """One detector per configured method, as it judges (`detector`)."""
        return [self.detector(name) for name in self.methods]

    @property
    def levels(self) -> frozenset[str]:
        """The levels its methods judge values at (`redline.detect.counters.one_cpu_figure`)."""
        return frozenset(detector.level for detector in self.detectors())

    def as_dict(self) -> dict[str, Any]:
        return {
            "methods": list(self.methods),
            "baseline": self.baseline,
            "window": self.window,
            "pinned": self.pinned,
            "thresholds": {k: dict(v) for k, v in self.thresholds.items()},
            "context_counters": list(self.context_counters),
            "confirm_revisions": self.confirm_revisions,
            "alarm_methods": list(self.alarm_methods),
            "confirm_pairs": self.confirm_pairs,
        }

    @property
    def alarming(self) -> tuple[str, ...]:
        """The methods whose flagged changes for the worse become regressions; counts of rare
        events (timeouts, losses) are judged by `CountRate` alone, which always alarms."""
        return (*(self.alarm_methods or self.methods[:1]), CountRate.name)


def _parameters(name: str) -> dict[str, Any]:
    """The keyword parameters of method ``name``'s detector, with their defaults."""
    parameters = list(inspect.signature(DETECTORS[name].__init__).parameters.items())[1:]
    return {key: parameter.default for key, parameter in parameters}
