"""The database tables (SQLAlchemy 2, typed), one module per concern; importing this package
registers every table on `Base.metadata`, which Alembic's autogenerate compares with the schema.
Schema changes go through Alembic (``redline/server/migrations``)."""

from redline.server.models.alerts import (
    Alert,
    AlertedChange,
    Delivery,
    RegressionTold,
    Subscription,
)
from redline.server.models.base import Base, utcnow
from redline.server.models.detection import (
    FALSE_POSITIVE_STATES,
    OPEN_STATES,
    STANDING,
    TRUE_POSITIVE_STATES,
    WITHDRAWN,
    Detection,
    DetectionConfigRow,
    JudgingConfig,
    Reanalysis,
    Regression,
    RegressionEvent,
    RegressionState,
    StagedDetection,
    StagedRevision,
)
from redline.server.models.learning import ResourceModelRow, RuntimeAlarm
from redline.server.models.results import FigureCache, Series, Summary
from redline.server.models.tokens import ApiToken, User, WebSession
from redline.server.models.work import (
    DID_NOT_RUN,
    FINISHED,
    HELD,
    UNENDED,
    Component,
    Execution,
    Host,
    Job,
    JobState,
    Revision,
    revision_place,
)

__all__ = [
    "DID_NOT_RUN",
    "FINISHED",
    "HELD",
    "UNENDED",
    "OPEN_STATES",
    "STANDING",
    "WITHDRAWN",
    "Alert",
    "AlertedChange",
    "RegressionTold",
    "Delivery",
    "Subscription",
    "FALSE_POSITIVE_STATES",
    "TRUE_POSITIVE_STATES",
    "ApiToken",
    "Base",
    "Component",
    "Detection",
    "DetectionConfigRow",
    "JudgingConfig",
    "Execution",
    "FigureCache",
    "Host",
    "Job",
    "JobState",
    "Reanalysis",
    "ResourceModelRow",
    "RuntimeAlarm",
    "Regression",
    "RegressionEvent",
    "RegressionState",
    "Revision",
    "revision_place",
    "StagedDetection",
    "StagedRevision",
    "Series",
    "Summary",
    "User",
    "WebSession",
    "utcnow",
]
