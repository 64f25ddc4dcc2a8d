"""Every detector Redline has, by the name that configurations, the API, the worker and
`redline evaluate` use: the one registry of methods."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

from redline.detect.association_rules import FooRules
from redline.detect.counter_clusters import ShangRegression
from redline.detect.execution_shift import CONFIRMED_THRESHOLD, BuildShift, ExecutionShift
from redline.detect.median_shift import MedianShift
from redline.detect.methods import Detector, KolmogorovSmirnov, MannWhitney, WelchT
from redline.detect.relative_change import RelativeChange

#: The methods a component can be configured with: each judges one series of one revision
#: against its baseline. Foo and Shang run in their one-counter form (a series is one counter).
DETECTORS: dict[str, Callable[..., Detector]] = {
    "execution_shift": ExecutionShift,
    "build_shift": BuildShift,
    "ks": KolmogorovSmirnov,
    "mann_whitney": MannWhitney,
    "welch_t": WelchT,
    "median_shift": MedianShift,
    "foo": FooRules,
    "shang": ShangRegression,
    "relative_change": RelativeChange,
}
#: What each method is, for a person choosing among them (the regressions page's filter)
TITLES: dict[str, str] = {
    "execution_shift": "execution shift, the default",
    "build_shift": "build shift",
    "ks": "Kolmogorov-Smirnov, charted",
    "mann_whitney": "Mann-Whitney U",
    "welch_t": "Welch's t-test",
    "median_shift": "median shift",
    "foo": "Foo et al. 2010, association rules",
    "shang": "Shang et al. 2015, counter clusters",
    "relative_change": "relative change",
}
#: Offline only: Foo's and Shang's scores aggregated as the paper also tried (min, mean).
VARIANTS: dict[str, Callable[..., Detector]] = {
    f"{name}.{how}": partial(kind, aggregate=how)
    for name, kind in (("foo", FooRules), ("shang", ShangRegression))
    for how in ("min", "mean")
}
#: Offline only: the default method at its confirmed threshold (6), as the service judges where
#: re-runs confirm; with `redline evaluate --confirm N`, what reaches the later revisions when
#: no pair could judge it (docs/detection.md, "The confirmed threshold").
VARIANTS["execution_shift.at6"] = partial(ExecutionShift, threshold=CONFIRMED_THRESHOLD)
#: What `redline evaluate` can measure per series.
EVALUATED: dict[str, Callable[..., Detector]] = {**DETECTORS, **VARIANTS}
#: Change points over a whole history (E-divisive): evaluated offline, not a per-revision method.
CHANGE_POINT_METHOD = "e_divisive"
#: Chosen on corpus 2's tuning half and checked on its held-out half and on SAP's set
#: (docs/detection.md, "Choosing the default").
DEFAULT_METHOD = "execution_shift"
