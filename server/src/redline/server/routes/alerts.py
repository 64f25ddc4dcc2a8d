"""Alerts and CI verdicts: subscriptions (a component's under /api/v1/components/{name}, every
component's under /api/v1/subscriptions), their delivery log, a component's commit-status
target, and a revision's verdict as JSON and JUnit XML. Subscriptions are an admin's."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Depends, Query, Response, status
from redline.server.api.deps import VERDICT_READ, SessionDep, require
from redline.server.core.bodies import JsonRoute
from redline.server.schemas.alerts import (
    CiVerdict,
    CommitStatusOut,
    CommitStatusTarget,
    DeliveryOut,
    SubscriptionCreate,
    SubscriptionOut,
    SubscriptionUpdate,
)
from redline.server.schemas.common import problems
from redline.server.services import ci_junit, ci_verdict, subscriptions
from redline.server.services.components import get_component

router = APIRouter(prefix="/api/v1", tags=["alerts"], route_class=JsonRoute)
ADMIN = [Depends(require("admin"))]
NOT_FOUND = problems(404, description="unknown component, subscription or revision")
Limit = Annotated[int, Query(ge=1, le=1000)]
#: what a failure is in a verdict's JUnit XML
Failures = Literal["regression", "any", "none"]
FailOn = Annotated[
    Failures,
    Query(description="what a failure is: a change for the worse, any change, or nothing"),
]


@router.post(
    "/components/{name}/subscriptions",
    status_code=status.HTTP_201_CREATED,
    responses=NOT_FOUND,
    dependencies=ADMIN,
)
def create_component_subscription(
    name: str, data: SubscriptionCreate, session: SessionDep
) -> SubscriptionOut:
    """Someone to tell about the component's changes; a webhook's secret is never shown again."""
    return subscriptions.create_subscription(session, name, data)


@router.get("/components/{name}/subscriptions", responses=NOT_FOUND, dependencies=ADMIN)
def list_component_subscriptions(name: str, session: SessionDep) -> list[SubscriptionOut]:
    return subscriptions.list_subscriptions(session, name)


@router.get("/components/{name}/subscriptions/{ident}", responses=NOT_FOUND, dependencies=ADMIN)
def get_component_subscription(name: str, ident: int, session: SessionDep) -> SubscriptionOut:
    found = subscriptions.get_subscription(session, name, ident)
    return subscriptions.subscription_out(found, name)


@router.patch("/components/{name}/subscriptions/{ident}", responses=NOT_FOUND, dependencies=ADMIN)
def update_component_subscription(
    name: str, ident: int, data: SubscriptionUpdate, session: SessionDep
) -> SubscriptionOut:
    return subscriptions.update_subscription(session, name, ident, data)


@router.delete(
    "/components/{name}/subscriptions/{ident}",
    status_code=status.HTTP_204_NO_CONTENT,
    responses=NOT_FOUND,
    dependencies=ADMIN,
)
def delete_component_subscription(name: str, ident: int, session: SessionDep) -> None:
    subscriptions.delete_subscription(session, name, ident)


@router.get(
    "/components/{name}/subscriptions/{ident}/deliveries",
    responses=NOT_FOUND,
    dependencies=ADMIN,
)
def component_subscription_deliveries(
    name: str, ident: int, session: SessionDep, limit: Limit = 100
) -> list[DeliveryOut]:
    """The subscription's deliveries, newest first: state, tries, last error, next try."""
    return subscriptions.list_deliveries(session, name, ident, limit)


@router.get("/components/{name}/deliveries", responses=NOT_FOUND, dependencies=ADMIN)
def component_deliveries(name: str, session: SessionDep, limit: Limit = 100) -> list[DeliveryOut]:
    """Everything sent about the component (its subscriptions' and its commit statuses)."""
    return subscriptions.list_deliveries(session, name, None, limit)


@router.post("/subscriptions", status_code=status.HTTP_201_CREATED, dependencies=ADMIN)
def create_subscription(data: SubscriptionCreate, session: SessionDep) -> SubscriptionOut:
    """Someone to tell about every component's changes."""
    return subscriptions.create_subscription(session, None, data)


@router.get("/subscriptions", dependencies=ADMIN)
def list_subscriptions(session: SessionDep) -> list[SubscriptionOut]:
    return subscriptions.list_subscriptions(session, None)


@router.get("/subscriptions/{ident}", responses=NOT_FOUND, dependencies=ADMIN)
def get_subscription(ident: int, session: SessionDep) -> SubscriptionOut:
    return subscriptions.subscription_out(
        subscriptions.get_subscription(session, None, ident), None
    )


@router.patch("/subscriptions/{ident}", responses=NOT_FOUND, dependencies=ADMIN)
def update_subscription(
    ident: int, data: SubscriptionUpdate, session: SessionDep
) -> SubscriptionOut:
    return subscriptions.update_subscription(session, None, ident, data)


@router.delete(
    "/subscriptions/{ident}",
    status_code=status.HTTP_204_NO_CONTENT,
    responses=NOT_FOUND,
    dependencies=ADMIN,
)
def delete_subscription(ident: int, session: SessionDep) -> None:
    subscriptions.delete_subscription(session, None, ident)


@router.get("/subscriptions/{ident}/deliveries", responses=NOT_FOUND, dependencies=ADMIN)
def subscription_deliveries(
    ident: int, session: SessionDep, limit: Limit = 100
) -> list[DeliveryOut]:
    return subscriptions.list_deliveries(session, None, ident, limit)


def _status_out(target: dict) -> CommitStatusOut | None:
    if not target:
        return None
    return CommitStatusOut(
        provider=target["provider"],
        api_url=target["api_url"],
        repository=target["repository"],
        has_token=bool(target.get("token")),
    )


@router.get("/components/{name}/commit-status", responses=NOT_FOUND, dependencies=ADMIN)
def get_commit_status(name: str, session: SessionDep) -> CommitStatusOut | None:
    """Where the component's verdicts go as commit statuses (null: nowhere)."""
    return _status_out(get_component(session, name).commit_status)


@router.put("/components/{name}/commit-status", responses=NOT_FOUND, dependencies=ADMIN)
def set_commit_status(
    name: str, data: CommitStatusTarget, session: SessionDep
) -> CommitStatusOut | None:
    """Post the verdicts of the component's revisions to GitHub's or GitLab's commit status
    API; the token is stored, never shown again."""
    component = get_component(session, name)
    component.commit_status = data.model_dump()
    session.commit()
    return _status_out(component.commit_status)


@router.delete(
    "/components/{name}/commit-status",
    status_code=status.HTTP_204_NO_CONTENT,
    responses=NOT_FOUND,
    dependencies=ADMIN,
)
def delete_commit_status(name: str, session: SessionDep) -> None:
    component = get_component(session, name)
    component.commit_status = {}
    session.commit()


@router.get(
    "/components/{name}/revisions/{title}/verdict", responses=NOT_FOUND, dependencies=VERDICT_READ
)
def revision_verdict(
    name: str,
    title: str,
    session: SessionDep,
    junit: Annotated[
        Failures | None,
        Query(description="also the verdict as JUnit XML (`junit`), failing on this"),
    ] = None,
) -> CiVerdict:
    """Whether the revision's verdict is settled, and per test case what was found; with
    ``junit``, its JUnit XML too, from the same reading (`redline ci wait --junit`: read in two
    requests, a result judged between them could make the file and the exit code disagree)."""
    verdict = ci_verdict.ci_verdict(session, name, title)
    if junit is not None:
        verdict.junit = ci_junit.junit_xml(verdict, junit)
    return verdict


@router.get(
    "/components/{name}/revisions/{title}/junit",
    responses={**NOT_FOUND, 200: {"content": {"application/xml": {}}}},
    dependencies=VERDICT_READ,
    response_class=Response,
)
def revision_junit(
    name: str, title: str, session: SessionDep, fail_on: FailOn = "regression"
) -> Response:
    """The verdict as JUnit XML: a testcase per test case x phase x parameter set, a failure
    per change ``fail_on`` counts, skipped where there is not enough data. The header
    ``X-Redline-Verdict`` says pending, done or failed (a pending file is not final)."""
    verdict = ci_verdict.ci_verdict(session, name, title)
    return Response(
        ci_junit.junit_xml(verdict, fail_on),
        media_type="application/xml",
        headers={"X-Redline-Verdict": verdict.state},
    )
