"""The trend charts a component's page shows by default, rendered after each analysis.

A page serves what is cached for its view and data version (`redline.server.services.dashboard`)
and renders only on a miss; the worker renders the default view as soon as a revision has been
analysed, so that the next visitor finds it ready.
"""

from __future__ import annotations

from redline.server.db import session_factory
from redline.server.models import Revision
from redline.server.services.dashboard import warm
from redline.server.ui.figures import trend_charts


def render_component_trends(database_url: str, component_id: int) -> None:
    with session_factory(database_url)() as session:  # warm() commits what it stores
        warm(session, component_id, trend_charts)


def render_revision_trends(database_url: str, revision_id: int) -> None:
    """The default trend view of the component the revision belongs to."""
    with session_factory(database_url)() as session:  # warm() commits what it stores
        revision = session.get(Revision, revision_id)
        if revision is not None:
            warm(session, revision.component_id, trend_charts)
