"""Change detection: pure detectors over numpy arrays, their aggregation and offline evaluation."""

from redline.detect.aggregate import aggregate, compare_test
from redline.detect.changepoint import EDivisive
from redline.detect.foo import FooRules
from redline.detect.methods import Detector, KolmogorovSmirnov, MannWhitney, WelchT
from redline.detect.result import CHANGE, NO_CHANGE, NOT_ENOUGH_DATA, Detection
from redline.detect.shang import ShangRegression

__all__ = [
    "CHANGE",
    "NO_CHANGE",
    "NOT_ENOUGH_DATA",
    "Detection",
    "Detector",
    "EDivisive",
    "FooRules",
    "KolmogorovSmirnov",
    "MannWhitney",
    "ShangRegression",
    "WelchT",
    "aggregate",
    "compare_test",
]
