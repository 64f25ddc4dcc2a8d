"""The resource-usage model: scaling, feature agglomeration, kernel ridge regression with an RBF
kernel, tuned by a grid search whose cross-validation folds are groups (execution x parameter set),
never a random split of neighbouring time steps (Wienke & Wrede, Section 6.1).

`ResourceModel` has scikit-learn's shape (fit, predict, get_params); `ModelFile` keeps one fitted
model per target with what it was made from, and refuses a file of another format or scikit-learn
version with a message saying so. A model file is a pickle: load only files you (or your Redline
server) made.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import joblib
import numpy as np
import sklearn
from redline.predict.dataset import DataError, Dataset
from redline.predict.features import FeatureSpec
from redline.predict.watch import calibrate
from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.cluster import FeatureAgglomeration
from sklearn.compose import TransformedTargetRegressor
from sklearn.kernel_ridge import KernelRidge
from sklearn.model_selection import GridSearchCV, GroupKFold, LeaveOneGroupOut
from sklearn.pipeline import Pipeline
from sklearn.preprocessing import StandardScaler

FORMAT = 2  # 2: features constant in training are left out (kept_)
#: the grid, as small as keeps a fit on a laptop under a minute for a few thousand steps
CLUSTERS = (4, 8, 16, 32)
ALPHAS = (1e-3, 1e-2, 1e-1, 1.0)
GAMMAS = (1e-3, 1e-2, 1e-1)
#: the alarm threshold is calibrated holding out one group at a time up to this many groups
ALONE_UP_TO = 50
#: fewer rows or groups than these leave nothing to cross-validate
MIN_ROWS, MIN_GROUPS = 10, 2


class ResourceModel(RegressorMixin, BaseEstimator):
    """Scaling → feature agglomeration → kernel ridge (RBF), its number of clusters, alpha and
    gamma chosen by grouped cross-validation on RMSE."""

    def __init__(
        self,
        clusters: tuple[int, ...] = CLUSTERS,
        alphas: tuple[float, ...] = ALPHAS,
        gammas: tuple[float, ...] = GAMMAS,
        folds: int = 5,
    ) -> None:
        self.clusters = clusters
        self.alphas = alphas
        self.gammas = gammas
        self.folds = folds

    def fit(self, x: np.ndarray, y: np.ndarray, groups: np.ndarray) -> ResourceModel:
        x, y, groups = np.asarray(x, float), np.asarray(y, float), np.asarray(groups)
        distinct = len(set(groups.tolist()))
        if len(y) < MIN_ROWS or distinct < MIN_GROUPS:
            raise DataError(
                f"too little to train on: {len(y)} time steps in {distinct} group(s) "
                f"(execution x parameter set); the grid search needs at least {MIN_ROWS} steps "
                f"in {MIN_GROUPS} groups"
            )
        # a feature constant in training teaches nothing, and scaled by a spread of 0 any other
        # value of it is an outlier of unbounded size (the sweep's pose messages were all 34
        # bytes, a replay's 35-49: every replay step lay "far" from training): left out
        self.kept_ = np.flatnonzero(np.var(x, axis=0) > 0)
        width = len(self.kept_)
        if width == 0:
            raise DataError(
                f"nothing to learn from: each of the {x.shape[1]} features has one value in "
                "every training step (the tests sent the same traffic throughout)"
            )
        x = x[:, self.kept_]
        clusters = sorted({min(c, width) for c in self.clusters if c >= 1}) or [1]
        pipeline = Pipeline(
            [
                ("scale", StandardScaler()),
                # agglomeration needs two features at least
                ("reduce", FeatureAgglomeration() if width > 1 else "passthrough"),
                ("regress", KernelRidge(kernel="rbf")),  # the default kernel is linear
            ]
        )
        # the target standardized too: kernel ridge has no intercept, and an RBF model of an
        # uncentred target falls to 0 away from its training points (an RSS of 50 MB "predicted"
        # as a few MB); centred, it falls back to the training mean instead
        model = TransformedTargetRegressor(regressor=pipeline, transformer=StandardScaler())
        grid: dict[str, list[float] | list[int]] = {
            "regressor__regress__alpha": list(self.alphas),
            "regressor__regress__gamma": list(self.gammas),
        }
        if width > 1:
            grid["regressor__reduce__n_clusters"] = clusters
        search = GridSearchCV(
            model,
            grid,
            cv=GroupKFold(n_splits=min(self.folds, distinct)),
            scoring="neg_root_mean_squared_error",
            n_jobs=1,
        )
        with warnings.catch_warnings():
            # constant features (a key silent in every step) make the scaler warn; harmless
            warnings.simplefilter("ignore", RuntimeWarning)
            search.fit(x, y, groups=groups)
        self.search_ = search
        self.best_params_ = {
            name.removeprefix("regressor__"): value for name, value in search.best_params_.items()
        }
        self.cv_rmse_ = float(-search.best_score_)
        self.threshold_ = calibrate(
            _held_out_residuals(search.best_estimator_, x, y, groups, min(self.folds, distinct)),
            float(np.mean(np.abs(y))),
        )
        return self

    def predict(self, x: np.ndarray) -> np.ndarray:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return self.search_.best_estimator_.predict(np.asarray(x, float)[:, self.kept_])


def _held_out_residuals(
    estimator: Any, x: np.ndarray, y: np.ndarray, groups: np.ndarray, folds: int
) -> list[np.ndarray]:
    """What the run-time alarm calibrates on: each group's residuals (in time order) from a model
    fitted on the other groups (up to `ALONE_UP_TO` groups, else on the other folds), for the
    groups whose mean usage lies within the range of the groups that model was fitted on.

    A group beyond every level its fold's model saw (the lowest or highest load of a sweep)
    measures an extrapolation that the deployed model, fitted on every group, does not make on
    traffic within its training range; counting it set thresholds several times the model's
    error in between (all groups are used when none is inside)."""
    levels = {group: float(np.mean(y[groups == group])) for group in dict.fromkeys(groups)}
    inside: list[np.ndarray] = []
    every: list[np.ndarray] = []
    # each group held out alone where that stays cheap: k folds over a few groups hold out
    # neighbours together, an interpolation over twice the gap the deployed model ever bridges
    splitter = LeaveOneGroupOut() if len(levels) <= ALONE_UP_TO else GroupKFold(n_splits=folds)
    for train, test in splitter.split(x, y, groups):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            predicted = sklearn.base.clone(estimator).fit(x[train], y[train]).predict(x[test])
        seen = [levels[group] for group in set(groups[train].tolist())]
        for group in dict.fromkeys(groups[test]):
            rows = groups[test] == group
            residuals = y[test][rows] - predicted[rows]
            every.append(residuals)
            if min(seen) <= levels[group] <= max(seen):
                inside.append(residuals)
    return inside or every


def errors(y: np.ndarray, predicted: np.ndarray) -> dict[str, float]:
    """RMSE, the RMSE of predicting the mean of ``y`` (the paper's baseline), and their ratio."""
    y = np.asarray(y, float)
    rmse = float(np.sqrt(np.mean((predicted - y) ** 2)))
    baseline = float(np.std(y))
    return {
        "rmse": rmse,
        "baseline_rmse": baseline,
        "ratio": rmse / baseline if baseline > 0 else float("inf"),
    }


def _versions() -> dict[str, str]:
    try:
        redline = metadata.version("redline-server")
    except metadata.PackageNotFoundError:
        redline = "unknown"
    return {"format": str(FORMAT), "scikit-learn": sklearn.__version__, "redline": redline}


@dataclass
class ModelFile:
    """A model per target for one component process, with its features and provenance."""

    spec: FeatureSpec
    process: str
    models: dict[str, ResourceModel]
    metrics: dict[str, dict[str, float]] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)
    versions: dict[str, str] = field(default_factory=_versions)
    #: keys the component answers on while it receives (`redline.predict.dataset.responses`)
    responses: tuple[str, ...] = ()

    @classmethod
    def fit(
        cls,
        data: Dataset,
        model: ResourceModel | None = None,
        targets: tuple[str, ...] | None = None,
        **provenance: Any,
    ) -> ModelFile:
        """A model per target (all of the data's by default), fitted on ``data``."""
        models, metrics = {}, {}
        for target, y in data.y.items():
            if targets is not None and target not in targets:
                continue
            fitted = sklearn.base.clone(model or ResourceModel()).fit(data.x, y, data.groups)
            models[target] = fitted
            metrics[target] = {
                "cv_rmse": fitted.cv_rmse_,
                "cv_baseline_rmse": float(np.std(y)),
                # None, not inf, for a constant target: JSON (and Postgres) has no infinity
                "cv_ratio": fitted.cv_rmse_ / float(np.std(y)) if np.std(y) > 0 else None,
                "threshold": fitted.threshold_,
                **{k: float(v) for k, v in fitted.best_params_.items()},
            }
        return cls(
            spec=data.spec,
            process=data.process,
            models=models,
            metrics=metrics,
            responses=data.responses,
            provenance={
                "recordings": data.sources,
                "steps": len(data.x),
                "groups": len(set(data.groups.tolist())),
                "left_out": data.left_out,
                "features": data.spec.names(),
                "grid": {
                    "clusters": list(ResourceModel().clusters),
                    "alphas": list(ResourceModel().alphas),
                    "gammas": list(ResourceModel().gammas),
                },
                **provenance,
            },
        )

    def predict(self, x: np.ndarray) -> dict[str, np.ndarray]:
        return {target: model.predict(x) for target, model in self.models.items()}

    def score(self, data: Dataset) -> dict[str, dict[str, float]]:
        predicted = self.predict(data.x)
        return {target: errors(data.y[target], predicted[target]) for target in self.models}

    def save(self, path: str | Path) -> None:
        joblib.dump(
            {
                "versions": self.versions,
                "spec": self.spec.to_dict(),
                "process": self.process,
                "models": self.models,
                "metrics": self.metrics,
                "provenance": self.provenance,
                "responses": list(self.responses),
            },
            path,
        )

    @classmethod
    def load(cls, path: str | Path) -> ModelFile:
        """The model in ``path``; DataError naming the cause when it cannot be used here."""
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error", sklearn.exceptions.InconsistentVersionWarning)
                data = joblib.load(path)
        except sklearn.exceptions.InconsistentVersionWarning as exc:
            raise DataError(
                f"{path}: made with scikit-learn {exc.original_sklearn_version}, this is "
                f"{sklearn.__version__}: fit it again here"
            ) from None
        except FileNotFoundError:
            raise DataError(f"{path}: no such model file") from None
        except Exception as exc:  # a pickle of something else, or a damaged file
            raise DataError(f"{path}: not a Redline model file ({type(exc).__name__})") from None
        if not isinstance(data, dict) or "versions" not in data:
            raise DataError(f"{path}: not a Redline model file")
        versions = data["versions"]
        if versions.get("format") != str(FORMAT):
            raise DataError(
                f"{path}: model file format {versions.get('format')}, this Redline reads "
                f"format {FORMAT}: fit it again"
            )
        if versions.get("scikit-learn") != sklearn.__version__:
            raise DataError(
                f"{path}: made with scikit-learn {versions.get('scikit-learn')}, this is "
                f"{sklearn.__version__}: fit it again here"
            )
        return cls(
            spec=FeatureSpec.from_dict(data["spec"]),
            process=data["process"],
            models=data["models"],
            metrics=data["metrics"],
            provenance=data["provenance"],
            versions=versions,
            responses=tuple(data.get("responses", ())),  # none in files made before them
        )
