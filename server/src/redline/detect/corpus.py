"""Labelled corpora for evaluating detectors: the format, the SAP HANA loader, evaluation units.

Format (see ``docs/detection.md``): a directory with ``measurements.parquet`` or
``measurements.csv`` (columns ``series``, ``build``, ``value`` and optionally ``execution``; one
row per sample, builds ordered by ``build``) and ``labels.json`` (``{"name", "source",
"license", "series": {id: {"label": str, "change_build": int | null}}}``, ``change_build`` being
the first build after the change; optionally the ``process`` and ``counter`` the series measures,
which `redline.detect.evaluate` judges as the service judges them). The SAP data set
(CC-BY-4.0, SAP/performance-regression-data-set, hana/small_2021) is read in its own layout and
turned into the same in-memory `Corpus`.
"""

from __future__ import annotations

import json
import os
from collections.abc import Container, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd
from redline.detect import counters

SAP_ENV = "REDLINE_SAP_CORPUS"
SAP_RELATIVE = Path("..") / "shared" / "data" / "sap-hana-small-2021"
SAP_ATTRIBUTION = (
    "SAP HANA performance regression data set (small, 2021), SAP SE, "
    "github.com/SAP/performance-regression-data-set, CC-BY-4.0"
)
POSITIVE_LABEL = "regression"
COLUMNS = ["series", "build", "value"]
EXECUTION = "execution"


class CorpusError(ValueError):
    """A corpus that cannot be found or read; the message names the path or field at fault."""


@dataclass(frozen=True)
class SeriesLabel:
    """A series' label and its labelled changes: ``change_build`` the first build after the
    first change, ``more`` the first builds after any further ones (each a positive unit);
    ``directions`` says which way each moved (``increase``/``decrease``, "" when not labelled).
    ``process`` and ``counter``: what the series measures, as the service names it (``driver``
    and ``Sequence/Query(key):rtt_p50_us`` for a test driver's metric); "" when not said."""

    label: str
    change_build: int | None = None
    more: tuple[int, ...] = ()
    directions: tuple[str, ...] = ()
    process: str = ""
    counter: str = ""

    @property
    def change_builds(self) -> tuple[int, ...]:
        """Every labelled change's first build, in order (empty unless a regression)."""
        if self.label != POSITIVE_LABEL or self.change_build is None:
            return ()
        return tuple(sorted({self.change_build, *self.more}))


def _label(entry: dict) -> SeriesLabel:
    """One series' entry of labels.json: ``change_build`` (one change) or ``change_builds``
    (several: ints, or ``{"build": int, "direction": "increase" | "decrease"}``)."""
    label = str(entry["label"])
    process, counter = str(entry.get("process", "")), str(entry.get("counter", ""))
    changes = entry.get("change_builds")
    if changes is None:
        first = entry.get("change_build")
        first_build = None if first is None else int(first)
        return SeriesLabel(label, first_build, process=process, counter=counter)
    builds, directions = [], []
    for change in changes:
        if isinstance(change, dict):
            builds.append(int(change["build"]))
            directions.append(str(change.get("direction", "")))
        else:
            builds.append(int(change))
            directions.append("")
    if not builds:
        return SeriesLabel(label, process=process, counter=counter)
    order = sorted(range(len(builds)), key=builds.__getitem__)
    ordered = [builds[i] for i in order]
    return SeriesLabel(
        label,
        ordered[0],
        tuple(ordered[1:]),
        tuple(directions[i] for i in order),
        process=process,
        counter=counter,
    )


@dataclass(frozen=True)
class Corpus:
    name: str
    measurements: pd.DataFrame  # series, build, execution, value; sorted by series, build
    labels: dict[str, SeriesLabel]
    source: str = ""
    license: str = ""


def counter_of(series: str) -> str:
    """The counter a series id names: its last ``/``-separated part (the whole id if none)."""
    return series.rsplit("/", 1)[-1]


@dataclass(frozen=True)
class Measures:
    """What the service makes of a corpus series (`measures`): the counter whose floor applies,
    whether it is judged, which way is worse ("" either way) and whether it counts rare events."""

    counter: str
    judged: bool = True
    worse: str = ""
    count: bool = False


def measures(series: str, label: SeriesLabel) -> Measures:
    """From the label's ``process`` and ``counter`` (the id's last part when it names none)."""
    counter = label.counter or counter_of(series)
    process = label.process
    if not process:
        return Measures(counter)
    return Measures(
        counter,
        counters.judged(process, counter),
        counters.worse(process, counter),
        counters.is_count(process, counter),
    )


def total_of(series: str, label: SeriesLabel, present: Container[str]) -> str | None:
    """The series a count of rare events is counted out of, found as the worker finds it
    (`redline.worker.history.count_totals`): the same place (the id before the counter) and the
    first of the metric's ``of`` fields (queries, waits...) the corpus holds."""
    metric = counters.driver_metric(label.process, label.counter)
    if metric is None or not label.counter or not series.endswith(label.counter):
        return None
    place = series[: len(series) - len(label.counter)]
    stem = label.counter.rpartition(":")[0]
    for field in metric.of:
        name = f"{place}{stem}:{field}" if stem else f"{place}{field}"
        if name in present:
            return name
    return None


@dataclass(frozen=True)
class Unit:
    """One evaluation case: a build of a series against the builds just before it.

    ``worse``: the direction a flag must take to be an alarm (``increase``/``decrease``; ""
    either way); ``count``: the values are counts of rare events, judged as a rate;
    ``history``: the executions of every build of the series (shared by its units, not
    copied) and ``at`` this build's place in it, for `past`."""

    series: str
    build: int
    baseline: np.ndarray
    candidate: np.ndarray
    positive: bool
    worse: str = ""
    count: bool = False
    history: Sequence[Sequence[np.ndarray]] = ()
    at: int = 0

    def past(self, builds: int) -> np.ndarray:
        """One value per execution (its median, as the service summarizes it) of the
        ``builds`` builds before this one, oldest first, whatever level a detector judges."""
        before = self.history[max(0, self.at - builds) : self.at]
        medians = [np.median(e) if len(e) else np.nan for build in before for e in build]
        return np.asarray(medians, dtype=np.float64)


def _repo_root() -> Path | None:
    for start in (Path.cwd(), Path(__file__).resolve()):
        for folder in (start, *start.parents):
            if (folder / "server").is_dir() and (folder / "agent").is_dir():
                return folder
    return None


def resolve_corpus(name_or_path: str) -> Path:
    """A corpus directory: an existing path, or "sap" (env REDLINE_SAP_CORPUS, else the
    repository root's ``../shared/data/sap-hana-small-2021``)."""
    if name_or_path.lower() != "sap":
        path = Path(name_or_path).expanduser()
        if not path.is_dir():
            raise CorpusError(f"corpus directory not found: {path}")
        return path
    candidates = [Path(os.environ[SAP_ENV])] if os.environ.get(SAP_ENV) else []
    root = _repo_root()
    if root is not None:
        candidates.append((root / SAP_RELATIVE).resolve())
    for path in candidates:
        if (path / "metadata" / "dataset_details.csv").is_file():
            return path
    tried = ", ".join(str(p) for p in candidates) or "nothing (no repository root found)"
    raise CorpusError(f"SAP corpus not found; tried {tried}; set {SAP_ENV}")


def load_sap(path: Path) -> Corpus:
    """The SAP HANA small-2021 set: series = file stem, build = GHC, value = Measurement."""
    details = path / "metadata" / "dataset_details.csv"
    meta = pd.read_csv(details, sep=";")
    frames, labels = [], {}
    for row in meta.itertuples(index=False):
        label, file, change_index = str(row[0]).strip(), str(row[1]).strip(), int(row[2])
        data = pd.read_csv(path / "data" / file)
        series = Path(file).stem
        change_build = None
        if label == POSITIVE_LABEL:
            after = data.loc[data["Index"] == change_index + 1, "GHC"]
            if after.empty:
                raise CorpusError(
                    f"{details}: change point {change_index} of {file} has no measurement after it"
                )
            change_build = int(after.iloc[0])
        labels[series] = SeriesLabel(label, change_build)
        frames.append(
            pd.DataFrame(
                {
                    "series": series,
                    "build": data["GHC"].astype(np.int64),
                    "value": data["Measurement"].astype(np.float64),
                }
            )
        )
    return Corpus(
        "sap-hana-small-2021",
        _sorted(pd.concat(frames)),
        labels,
        source=SAP_ATTRIBUTION,
        license="CC-BY-4.0",
    )


def _sorted(frame: pd.DataFrame) -> pd.DataFrame:
    """Sorted by series and build, with an ``execution`` column: where the corpus has none,
    every sample is taken for its own execution (a repeated run of the benchmark, as SAP's)."""
    frame = frame.sort_values(["series", "build"], kind="stable").reset_index(drop=True)
    if EXECUTION not in frame.columns:
        frame[EXECUTION] = frame.groupby(["series", "build"]).cumcount()
    return frame[[*COLUMNS, EXECUTION]].astype({EXECUTION: np.int64})


def load_generic(path: Path) -> Corpus:
    """A corpus in Redline's own format (``measurements.{parquet,csv}`` + ``labels.json``)."""
    parquet, csv = path / "measurements.parquet", path / "measurements.csv"
    frame = pd.read_parquet(parquet) if parquet.is_file() else pd.read_csv(csv)
    missing = set(COLUMNS) - set(frame.columns)
    if missing:
        raise CorpusError(f"{path}: measurements lack columns {sorted(missing)}")
    meta = json.loads((path / "labels.json").read_text())
    kept = [*COLUMNS, EXECUTION] if EXECUTION in frame.columns else COLUMNS
    frame = frame[kept].astype({"series": str, "build": np.int64, "value": np.float64})
    labels = {str(series): _label(entry) for series, entry in meta.get("series", {}).items()}
    return Corpus(
        str(meta.get("name", path.name)),
        _sorted(frame),
        labels,
        source=str(meta.get("source", "")),
        license=str(meta.get("license", "")),
    )


def load_corpus(name_or_path: str) -> Corpus:
    path = resolve_corpus(name_or_path)
    if (path / "metadata" / "dataset_details.csv").is_file():
        return load_sap(path)
    if (path / "labels.json").is_file():
        return load_generic(path)
    raise CorpusError(f"{path}: neither labels.json nor metadata/dataset_details.csv")


def _entry(label: SeriesLabel) -> dict:
    measures = {
        key: value
        for key, value in (("process", label.process), ("counter", label.counter))
        if value
    }
    if not label.more and not any(label.directions):
        return {"label": label.label, "change_build": label.change_build, **measures}
    builds = [label.change_build, *label.more]
    directions = label.directions or ("",) * len(builds)
    return {
        "label": label.label,
        "change_builds": [
            {"build": b, "direction": d} for b, d in zip(builds, directions, strict=True)
        ],
        **measures,
    }


def write_corpus(corpus: Corpus, path: Path) -> None:
    """Write a corpus in Redline's format (Parquet + labels.json), e.g. to convert SAP's."""
    path.mkdir(parents=True, exist_ok=True)
    corpus.measurements.to_parquet(path / "measurements.parquet", index=False)
    series = {s: _entry(lab) for s, lab in corpus.labels.items()}
    meta = {
        "name": corpus.name,
        "source": corpus.source,
        "license": corpus.license,
        "series": series,
    }
    (path / "labels.json").write_text(json.dumps(meta, indent=1) + "\n")


def series_builds(
    corpus: Corpus,
) -> Iterator[tuple[str, SeriesLabel, list[tuple[int, list[np.ndarray]]]]]:
    """Each series with its label and its builds in order, a build as its executions' samples
    (without an ``execution`` column, every sample is its own execution, as the loader says).

    One sort and one pass over plain arrays: a pandas group-by per build and execution took
    nine-tenths of an evaluation of 300,000 builds.
    """
    frame = corpus.measurements
    if EXECUTION not in frame.columns:
        frame = _sorted(frame)
    frame = frame.sort_values(["series", "build", EXECUTION], kind="stable")
    series = frame["series"].to_numpy()
    builds = frame["build"].to_numpy(dtype=np.int64)
    executions = frame[EXECUTION].to_numpy(dtype=np.int64)
    values = frame["value"].to_numpy(dtype=np.float64)
    if not len(values):
        return
    new_series = np.r_[True, series[1:] != series[:-1]]
    new_build = new_series | np.r_[True, builds[1:] != builds[:-1]]
    new_execution = new_build | np.r_[True, executions[1:] != executions[:-1]]
    starts = np.flatnonzero(new_execution)
    runs = np.split(values, starts[1:])
    run_build = new_build[starts]
    run_series = new_series[starts]
    current: list[tuple[int, list[np.ndarray]]] = []
    name = ""
    for index, start in enumerate(starts):
        if run_series[index]:
            if current:
                yield name, corpus.labels.get(name, SeriesLabel("unlabelled")), current
            name, current = str(series[start]), []
        if run_build[index]:
            current.append((int(builds[start]), []))
        current[-1][1].append(runs[index])
    yield name, corpus.labels.get(name, SeriesLabel("unlabelled")), current


def first_executions(corpus: Corpus, count: int) -> Corpus:
    """The corpus as if every build had run only its first ``count`` executions."""
    frame = corpus.measurements
    ranks = frame.groupby(["series", "build"])["execution"].rank(method="dense")
    return replace(corpus, measurements=frame[ranks <= count].reset_index(drop=True))
