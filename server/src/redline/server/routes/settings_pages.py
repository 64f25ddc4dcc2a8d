"""The settings pages, for administrators: a component's settings, detection configuration and
alert subscriptions, the subscriptions to every component's alerts, API tokens (created, shown
once, revoked) and the performance hosts. A webhook's secret, like a token, is never shown back.

Reading them needs an ``admin`` sign-in (they show where code comes from and who holds tokens);
every change posts the session's form token and needs ``admin``, as the API does.
"""

from __future__ import annotations

import json
from urllib.parse import quote

from fastapi import Request, Response
from fastapi.responses import HTMLResponse, RedirectResponse
from pydantic import ValidationError
from redline.server.api.deps import SessionDep, SettingsDep
from redline.server.core.bodies import BadJson, parse_json
from redline.server.core.security import grants
from redline.server.schemas.alerts import SubscriptionCreate, SubscriptionUpdate
from redline.server.schemas.components import ComponentSettings
from redline.server.schemas.fields import escaped
from redline.server.schemas.regressions import DetectionConfigIn
from redline.server.services import (
    component_deletion,
    components,
    detection_config,
    home,
    signin,
    subscriptions,
    tokens,
)
from redline.server.services.errors import (
    BadRequest,
    Conflict,
    Forbidden,
    NotFound,
    Unprocessable,
)
from redline.server.ui.pages import form_errors, form_fields, page, page_router, problem, signed_in

ADMIN = "admin"
router = page_router()


def _admin(request: Request) -> None:
    """A signed-in administrator may read the settings; Forbidden naming what is missing."""
    row = signed_in(request)
    if row is None:
        raise Forbidden("sign in as an administrator to see the settings")
    if not grants(list(row.scopes), ADMIN):
        raise Forbidden(f"{row.who} lacks the 'admin' scope")


def _settings(request: Request, session: SessionDep, created: str | None) -> HTMLResponse:
    """The settings page; ``created``: a token just made, shown this once."""
    everywhere = subscriptions.list_subscriptions(session, None)
    context = {
        "components": components.list_components(session),
        "subscriptions": everywhere,
        "deliveries": subscriptions.recent_deliveries(session, everywhere),
        "tokens": tokens.list_tokens(session),
        "hosts": home.list_hosts(session),
        "created": created,
    }
    return page(request, "settings.html", context)


def _filters(form: dict[str, str]) -> dict[str, object]:
    """A subscription form's filters, as the API takes them (minimum effect in %)."""
    try:
        min_effect = float(form.get("min_effect") or 0) / 100
    except ValueError as exc:
        raise BadRequest(f"minimum effect: a number ({exc})") from None
    return {
        "counters": [c.strip() for c in form.get("counters", "").split(",") if c.strip()],
        "direction": form.get("direction") or None,
        "min_effect": min_effect,
        "confirmed_only": form.get("confirmed_only") == "1",
        "delivery": form.get("delivery") or None,
    }


def _new_subscription(form: dict[str, str]) -> SubscriptionCreate:
    kind = form.get("kind", "")
    target = {
        "kind": kind,
        "address": form.get("address", "").strip() if kind == "email" else "",
        "url": form.get("url", "").strip() if kind == "webhook" else "",
        "secret": form.get("secret", "") if kind == "webhook" else "",
        "format": form.get("format") or "redline",
    }
    try:
        return SubscriptionCreate.model_validate({**target, **_filters(form)})
    except ValidationError as exc:
        raise BadRequest(form_errors(exc)) from None


def _changed_subscription(form: dict[str, str]) -> SubscriptionUpdate:
    """What an edit form changes: the target fields it has (an email's address; a webhook's
    url and format, and its secret only when a new one is given or it is removed) and every
    filter."""
    fields: dict[str, object] = {
        name: form[name].strip() for name in ("address", "url", "format") if name in form
    }
    if form.get("clear_secret") == "1":
        fields["secret"] = ""
    elif form.get("secret"):
        fields["secret"] = form["secret"]
    try:
        given = {name: value for name, value in _filters(form).items() if value is not None}
        return SubscriptionUpdate.model_validate({**fields, **given})
    except ValidationError as exc:
        raise BadRequest(form_errors(exc)) from None


SUBSCRIPTION_ERRORS = (Forbidden, NotFound, BadRequest, Unprocessable)


@router.get("/settings", response_class=HTMLResponse)
def settings_page(request: Request, session: SessionDep) -> HTMLResponse:
    try:
        _admin(request)
    except Forbidden as exc:
        return problem(request, exc)
    return _settings(request, session, created=None)


@router.get("/settings/components/{name}", response_class=HTMLResponse)
def component_settings_page(name: str, request: Request, session: SessionDep) -> HTMLResponse:
    try:
        _admin(request)
        component = components.get_component(session, name)
    except (Forbidden, NotFound) as exc:
        return problem(request, exc)
    config = detection_config.get_config(session, name).model_dump()
    listed = subscriptions.list_subscriptions(session, name)
    return page(
        request,
        "component_settings.html",
        {
            "component": component,
            "config": json.dumps(config, indent=2),
            "subscriptions": listed,
            "deliveries": subscriptions.recent_deliveries(session, listed),
        },
    )


async def _subscription_form(
    request: Request, session: SessionDep, component: str | None, ident: int | None, action: str
) -> Response:
    """Make (``ident`` None), change or delete one of the component's subscriptions (None:
    one to every component's), as the API does, then back to the list."""
    form = await form_fields(request)
    try:
        signin.authorize(signed_in(request), form.get("csrf", ""), ADMIN)
        if ident is None:
            subscriptions.create_subscription(session, component, _new_subscription(form))
        elif action == "delete":
            subscriptions.delete_subscription(session, component, ident)
        else:
            changed = _changed_subscription(form)
            subscriptions.update_subscription(session, component, ident, changed)
    except SUBSCRIPTION_ERRORS as exc:
        return problem(request, exc)
    where = f"/settings/components/{component}" if component else "/settings"
    return RedirectResponse(f"{where}#alerts", status_code=303)


@router.post("/settings/components/{name}/subscriptions", response_class=HTMLResponse)
async def subscribe_form(name: str, request: Request, session: SessionDep) -> Response:
    """A subscription to the component's alerts, as the API's POST makes it."""
    return await _subscription_form(request, session, name, None, "create")


@router.post("/settings/components/{name}/subscriptions/{ident}", response_class=HTMLResponse)
async def change_subscription_form(
    name: str, ident: int, request: Request, session: SessionDep
) -> Response:
    """The component's subscription changed, as the API's PATCH changes it."""
    return await _subscription_form(request, session, name, ident, "change")


@router.post(
    "/settings/components/{name}/subscriptions/{ident}/delete", response_class=HTMLResponse
)
async def unsubscribe_form(
    name: str, ident: int, request: Request, session: SessionDep
) -> Response:
    return await _subscription_form(request, session, name, ident, "delete")


@router.post("/settings/subscriptions", response_class=HTMLResponse)
async def subscribe_everywhere_form(request: Request, session: SessionDep) -> Response:
    """A subscription to every component's alerts."""
    return await _subscription_form(request, session, None, None, "create")


@router.post("/settings/subscriptions/{ident}", response_class=HTMLResponse)
async def change_everywhere_form(ident: int, request: Request, session: SessionDep) -> Response:
    return await _subscription_form(request, session, None, ident, "change")


@router.post("/settings/subscriptions/{ident}/delete", response_class=HTMLResponse)
async def unsubscribe_everywhere_form(
    ident: int, request: Request, session: SessionDep
) -> Response:
    return await _subscription_form(request, session, None, ident, "delete")


@router.post("/settings/components/{name}", response_class=HTMLResponse)
async def component_settings_form(
    name: str, request: Request, session: SessionDep, settings: SettingsDep
) -> Response:
    """Store a component's settings and detection configuration; a configuration change
    queues a re-analysis of its history, as the API's does."""
    form = await form_fields(request)
    try:
        signin.authorize(signed_in(request), form.get("csrf", ""), ADMIN)
        component = components.get_component(session, name)
        try:
            changed = ComponentSettings(
                repo=form.get("repo") or None,
                branch=form.get("branch") or None,
                suite=form.get("suite") or None,
                executions=int(form["executions"]) if form.get("executions") else None,
            )
            config = DetectionConfigIn.model_validate(
                parse_json((form.get("config") or "{}").encode())
            )
        except BadJson as exc:  # as the API's body: '[' * 2000 was a 500 (an audit)
            raise BadRequest(f"detection configuration: {exc}") from None
        except ValidationError as exc:
            raise BadRequest(form_errors(exc)) from None
        except ValueError:  # int()'s own words ("invalid literal for int() with base 10")
            given = escaped(form.get("executions", "")[:40])
            raise BadRequest(f"executions: must be a whole number, not {given!r}") from None
        components.update_component(session, name, changed, settings.allow_file_repos)
        before = detection_config.get_config(session, name)
        detection_config.set_config(session, name, config)
        if detection_config.get_config(session, name) != before and config.reanalyze:
            detection_config.request_reanalysis(session, component)
            request.app.state.tasks.reanalyze(component.id)
    except (Forbidden, NotFound, BadRequest, Conflict) as exc:
        return problem(request, exc)
    return RedirectResponse(f"/settings/components/{name}", status_code=303)


@router.post("/components/{name}/revisions/{title}/delete", response_class=HTMLResponse)
async def delete_revision_form(
    name: str, title: str, request: Request, session: SessionDep
) -> Response:
    """Delete a revision of which nothing was measured (its page offers it to an admin), as
    the API's ``DELETE`` does; then the component's page."""
    form = await form_fields(request)
    try:
        signin.authorize(signed_in(request), form.get("csrf", ""), ADMIN)
        component_deletion.delete_revision(session, name, title)
    except (Forbidden, NotFound, Conflict) as exc:
        return problem(request, exc)
    return RedirectResponse(f"/components/{quote(name, safe='')}", status_code=303)


@router.post("/settings/tokens", response_class=HTMLResponse)
async def create_token_form(request: Request, session: SessionDep) -> HTMLResponse:
    """A new API token, shown once on the page that answers."""
    form = await form_fields(request)
    try:
        signin.authorize(signed_in(request), form.get("csrf", ""), ADMIN)
        _, secret = tokens.issue_token(
            session,
            form.get("name", "").strip(),
            form.get("scopes", ""),
            form.get("host") or None,
            form.get("labels", ""),
            form.get("components", ""),
        )
    except (Forbidden, BadRequest, Conflict) as exc:
        return problem(request, exc)
    return _settings(request, session, created=secret)


@router.post("/settings/tokens/{token_id}/revoke", response_class=HTMLResponse)
async def revoke_token_form(token_id: int, request: Request, session: SessionDep) -> Response:
    form = await form_fields(request)
    try:
        signin.authorize(signed_in(request), form.get("csrf", ""), ADMIN)
        tokens.revoke_token(session, str(token_id))
    except (Forbidden, NotFound) as exc:
        return problem(request, exc)
    return RedirectResponse("/settings", status_code=303)
