"""Training a resource-usage model as a worker task (`redline.predict`): the requested executions'
recordings read, the model fitted and written beside the recordings (``models/<id>.joblib``), and
its metrics, provenance and a measured-and-predicted series for the pages stored."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from redline.predict.dataset import DataError, dataset, read_run
from redline.predict.model import ModelFile
from redline.server.db import session_scope
from redline.server.models import ResourceModelRow, Revision, utcnow
from redline.server.services.errors import ServiceError
from redline.server.services.learning import chosen_executions

log = logging.getLogger(__name__)
#: points of the measured-and-predicted series kept for the pages
PLOT_POINTS = 600


def train_model(database_url: str, storage_dir: Path, model_id: int) -> None:
    with session_scope(database_url) as session:
        row = session.get(ResourceModelRow, model_id)
        if row is None or row.state not in ("queued", "running"):
            return  # gone, or trained already (a redelivered task)
        row.state = "running"
        try:
            executions = chosen_executions(session, row.component_id, row.request)
        except ServiceError as exc:
            row.state, row.error, row.finished = "failed", exc.detail, utcnow()
            return
        chosen = [(e.id, e.recording_path, e.revision_id) for e in executions]
        titles = {
            r.id: r.title
            for r in session.query(Revision).filter(Revision.id.in_({c[2] for c in chosen}))
        }
        request = dict(row.request)
    try:
        runs = [read_run(path) for _, path, _ in chosen]
        case = request.get("case")
        data = dataset(
            runs,
            request.get("process"),
            keep=(lambda s: s.case == case) if case else None,
            received_only=bool(request.get("received_only")),
        )
        model = ModelFile.fit(
            data,
            executions=[ident for ident, _, _ in chosen],
            revisions=sorted({titles[r] for _, _, r in chosen}),
        )
        path = storage_dir / "models" / f"{model_id}.joblib"
        path.parent.mkdir(parents=True, exist_ok=True)
        model.save(path)
    except DataError as exc:
        with session_scope(database_url) as session:
            row = session.get_one(ResourceModelRow, model_id)
            row.state, row.error, row.finished = "failed", str(exc), utcnow()
        log.warning("model %s: %s", model_id, exc)
        return
    predicted = model.predict(data.x)
    keep = np.unique(np.linspace(0, len(data.x) - 1, min(PLOT_POINTS, len(data.x))).astype(int))
    plot = {
        "t": ((data.times[keep] - data.times[0]) / 1e9).round(2).tolist(),
        "group": data.groups[keep].tolist(),
        **{
            target: {
                "measured": data.y[target][keep].round(3).tolist(),
                "predicted": predicted[target][keep].round(3).tolist(),
            }
            for target in model.models
        },
    }
    with session_scope(database_url) as session:
        row = session.get_one(ResourceModelRow, model_id)
        row.state, row.finished, row.path = "done", utcnow(), str(path)
        row.process, row.metrics, row.provenance = (
            model.process,
            model.metrics,
            {
                **model.provenance,
                "versions": model.versions,
            },
        )
        row.plot = plot
