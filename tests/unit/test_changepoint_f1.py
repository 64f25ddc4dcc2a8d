"""TCPDBench's change-point F1 (`redline.detect.changepoint_f1`) on cases worked by hand, and
binary segmentation finding a clear step."""

from __future__ import annotations

import numpy as np
import pytest
from redline.detect.changepoint_f1 import binary_segmentation, f_measure


def test_a_prediction_within_the_margin_is_a_true_positive_and_outside_it_is_not() -> None:
    assert f_measure({"a": [50]}, [50]) == (1.0, 1.0, 1.0)
    assert f_measure({"a": [50]}, [55])[0] == 1.0  # 5 builds off: inside the margin
    f, precision, recall = f_measure({"a": [50]}, [56])  # 6 off: a false alarm and a miss
    assert (precision, recall) == (0.5, 0.5) and f == pytest.approx(0.5)


def test_a_detector_that_never_alarms_is_scored_through_the_start_point() -> None:
    f, precision, recall = f_measure({"a": [50]}, [])
    assert (precision, recall) == (1.0, 0.5) and f == pytest.approx(2 / 3)
    assert f_measure({"a": []}, []) == (1.0, 1.0, 1.0)  # nothing to find, nothing claimed
    assert f_measure({"a": []}, [10, 20])[1] == pytest.approx(1 / 3)  # two false alarms


def test_each_annotated_point_is_matched_once_and_recall_is_averaged_over_annotators() -> None:
    _, precision, _ = f_measure({"a": [50]}, [49, 51])  # one of the two is a true positive
    assert precision == pytest.approx(2 / 3)
    f, precision, recall = f_measure({"a": [50], "b": [50, 80]}, [50])
    assert precision == 1.0 and recall == pytest.approx((1.0 + 2 / 3) / 2)


def test_binary_segmentation_finds_a_clear_step_and_nothing_in_noise() -> None:
    rng = np.random.default_rng(3)
    step = np.r_[rng.normal(10, 0.2, 40), rng.normal(13, 0.2, 40)]
    assert binary_segmentation(step) == [40]
    assert binary_segmentation(rng.normal(10, 0.2, 80)) == []
    assert binary_segmentation([1.0, 2.0]) == []
