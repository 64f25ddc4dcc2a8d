"""What an alert says, and how each channel says it: the JSON of an outgoing webhook (Redline's
own, documented in docs/alerts.md with its JSON Schema, or Slack's), and a mail's subject, plain
text and HTML.

Alert bodies are stored with paths (``/regressions/7``); the links become absolute with
``REDLINE_PUBLIC_URL`` when a message is rendered, so a changed public address applies to
messages still waiting to be sent.
"""

from __future__ import annotations

import html
import json
from datetime import datetime
from typing import Any
from urllib.parse import quote, urlencode

from redline.detect.result import effect_size
from redline.recording import params_name
from redline.server.models import Detection, Regression, Revision, RuntimeAlarm, Series
from redline.server.services.read import param_text, revision_page

#: the version of the webhook payload (docs/alerts.md); a breaking change raises it
SCHEMA_VERSION = 1


def _chart_path(component: str, series: Series) -> str:
    """The component page filtered to the series' chart, its parameter set too, as the page's
    own filters say it (`param.NAME`; a trial's alert opened every parameter set's chart)."""
    query = {"case": series.case, "phase": series.phase, "process": series.process}
    query["counter"] = series.counter
    params = json.loads(series.params or "{}")
    query |= {f"param.{name}": param_text(value) for name, value in sorted(params.items())}
    return f"/components/{quote(component)}?{urlencode(query)}"


def change_body(
    component: str,
    detection: Detection,
    series: Series,
    revision: Revision,
    baseline: str | None,
) -> dict[str, Any]:
    return {
        "case": series.case,
        "phase": series.phase,
        "parameters": json.loads(series.params) if series.params.startswith("{") else {},
        "process": series.process,
        "counter": series.counter,
        "method": detection.method,
        "effect": detection.effect,
        "p_value": detection.p_value,
        "direction": detection.direction,
        "confirmation": detection.confirmation or "none",
        "revision": {
            "title": revision.title,
            "commit": revision.commit,
            "page": revision_page(component, revision.title),
        },
        "baseline": baseline,
        "chart": _chart_path(component, series),
    }


def _effect(change: dict[str, Any]) -> str:
    """A flagged change's size; one without a ratio rose or fell from a zero baseline."""
    effect = change.get("effect")
    return "from 0" if effect is None else f"{effect * 100:+.1f} %"


def _summary(component: str, kind: str, changes: list[dict[str, Any]]) -> str:
    """One line for a subject: the largest change, with its parameter set; the component's own
    process is not named twice. (A trial's read "objectbuilder: regression: objectbuilder
    cpu_percent +139.4 % at df29d8d18358 and 4 more series", the first series, not the +158 %.)"""
    first = max(changes, key=lambda change: effect_size(change.get("effect")))
    more = f" and {len(changes) - 1} more series" if len(changes) > 1 else ""
    what = {
        "regression": "regression",
        "regression.updated": "regression grew",
        "regression.confirmed": "regression confirmed",
        "regression.not_confirmed": "regression not confirmed",
        "regression.withdrawn": "regression withdrawn",
        "improvement": "improvement",
    }.get(kind, kind)
    who = "" if first["process"] == component else f"{first['process']} "
    params = f" [{params_name(first['parameters'])}]" if first.get("parameters") else ""
    return (
        f"{component}: {what}: {who}{first['counter']} {_effect(first)}{params} "
        f"at {first['revision']['title']}{more}"
    )


def alert_body(
    component: str, kind: str, regression: Regression | None, changes: list[dict[str, Any]]
) -> dict[str, Any]:
    body: dict[str, Any] = {
        "kind": kind,
        "component": component,
        "summary": _summary(component, kind, changes),
        "regression": None,
        "changes": changes,
    }
    if regression is not None:
        body["regression"] = regression_body(regression)
    return body


def regression_body(regression: Regression) -> dict[str, Any]:
    """The regression as an alert tells it: as it is at the time the message is made."""
    return {
        "id": regression.id,
        "page": f"/regressions/{regression.id}",
        "state": regression.state.value,
        "confirmation": regression.confirmation,
        "confirmation_reason": regression.confirmation_reason,
        "good": {"title": regression.good_revision.title},
        "bad": {"title": regression.bad_revision.title, "subject": regression.bad_revision.subject},
    }


def runtime_body(component: str, alarm: RuntimeAlarm) -> dict[str, Any]:
    """A fault `redline watch` saw on the running component (or its end)."""
    kind = "runtime_fault" if alarm.started else "runtime_fault.over"
    side = "above" if alarm.residual > 0 else "below"
    where = " on ".join(part for part in (alarm.process, alarm.host) if part)
    summary = (
        f"{component}: run-time fault: {alarm.target} {side} what its traffic predicts by "
        f"{abs(alarm.residual):.4g} (threshold {alarm.threshold:.4g})"
        if alarm.started
        else f"{component}: run-time fault over: {alarm.target} back within {alarm.threshold:.4g}"
        " of what its traffic predicts"
    ) + (f" ({where})" if where else "")
    return {
        "kind": kind,
        "component": component,
        "summary": summary,
        "runtime": {
            "id": alarm.id,
            "target": alarm.target,
            "started": alarm.started,
            "residual": alarm.residual,
            "threshold": alarm.threshold,
            "step": alarm.step,
            "host": alarm.host,
            "process": alarm.process,
            "model": alarm.model_id,
            "at": alarm.at.isoformat(),
            "page": f"/components/{quote(component)}#runtime-alerts",
        },
    }


def digest_body(alerts: list[dict[str, Any]]) -> dict[str, Any]:
    return {"alerts": alerts}


def _absolute(value: Any, public_url: str) -> Any:
    """The body with every ``page`` and ``chart`` path also given as an absolute ``url``."""
    if isinstance(value, list):
        return [_absolute(item, public_url) for item in value]
    if not isinstance(value, dict):
        return value
    out = {key: _absolute(item, public_url) for key, item in value.items()}
    for key in ("page", "chart"):
        if isinstance(out.get(key), str):
            out[f"{key}_url"] = public_url.rstrip("/") + out[key]
    return out


def _alerts(payload: dict[str, Any]) -> list[dict[str, Any]]:
    return payload.get("alerts", [payload])


def webhook_json(
    event: str, uid: str, payload: dict[str, Any], public_url: str, sent: datetime
) -> dict[str, Any]:
    """Redline's own webhook body (docs/alerts.schema.json)."""
    return {
        "schema": SCHEMA_VERSION,
        "event": event,
        "delivery": uid,
        "sent_at": sent.isoformat(),
        "alerts": _absolute(_alerts(payload), public_url),
    }


def slack_json(event: str, payload: dict[str, Any], public_url: str) -> dict[str, Any]:
    """A body Slack's incoming webhooks (and Mattermost's, and Rocket.Chat's) accept."""
    lines = []
    for alert in _absolute(_alerts(payload), public_url):
        link = (alert.get("regression") or alert.get("runtime") or {}).get("page_url") or alert[
            "changes"
        ][0]["revision"]["page_url"]  # an improvement: its revision's page
        lines.append(f"<{link}|{_slack_escape(alert['summary'])}>")
    title = "Redline digest" if event == "digest" else "Redline"
    return {"text": f"*{title}*\n" + "\n".join(lines)}


def _slack_escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _change_line(change: dict[str, Any]) -> str:
    params = ", ".join(f"{k}={v}" for k, v in change["parameters"].items())
    return (
        f"{change['case']} / {change['phase']}"
        + (f" [{params}]" if params else "")
        + f": {change['process']} {change['counter']} {_effect(change)}"
        + f" ({change['method']}, p={change['p_value'] if change['p_value'] is not None else 'n/a'}"
        + f", {change['confirmation']}) at {change['revision']['title']}"
        + (f" against {change['baseline']}" if change["baseline"] else "")
    )


def email(event: str, payload: dict[str, Any], public_url: str) -> tuple[str, str, str]:
    """A mail's subject, plain text and HTML."""
    alerts = _absolute(_alerts(payload), public_url)
    if event == "digest":
        subject = f"[Redline] digest: {len(alerts)} alert(s)"
    else:
        subject = f"[Redline] {alerts[0]['summary']}"
    text_parts, html_parts = [], []
    for alert in alerts:
        regression = alert.get("regression")
        head = alert["summary"]
        text_parts.append(head)
        html_parts.append(f"<h2>{html.escape(head)}</h2>")
        if regression:
            commit = regression["bad"].get("subject")  # its commit message's first line
            said = (
                f"Regression #{regression['id']} between {regression['good']['title']} and "
                f"{regression['bad']['title']}"
                + (f" ({commit!r})" if commit else "")
                + f": {regression['confirmation']}"
                + (
                    f" ({regression['confirmation_reason']})"
                    if regression["confirmation_reason"]
                    else ""
                )
                + (f"; triaged: {regression['state']}" if regression["state"] != "new" else "")
            )
            text_parts.append(said)
            text_parts.append(f"Regression: {regression['page_url']}")
            html_parts.append(
                f"<p>{html.escape(said)}. "
                f'<a href="{html.escape(regression["page_url"])}">Open the regression</a></p>'
            )
        elif alert.get("changes"):  # an improvement: no regression, its revision's page
            page = alert["changes"][0]["revision"]["page_url"]
            text_parts.append(f"Revision: {page}")
            html_parts.append(f'<p><a href="{html.escape(page)}">Open the revision</a></p>')
        runtime = alert.get("runtime")
        if runtime:
            text_parts.append(f"Component: {runtime['page_url']}")
            html_parts.append(
                f'<p><a href="{html.escape(runtime["page_url"])}">Open the component</a></p>'
            )
        html_parts.append("<ul>")
        for change in alert.get("changes", []):
            line = _change_line(change)
            text_parts.append(f"  - {line}\n    chart: {change['chart_url']}")
            html_parts.append(
                f"<li>{html.escape(line)} "
                f'(<a href="{html.escape(change["chart_url"])}">chart</a>)</li>'
            )
        html_parts.append("</ul>")
        text_parts.append("")
    text = "\n".join(text_parts) + "\n-- \nRedline: you get this as a subscriber of these alerts.\n"
    body = "<html><body>" + "".join(html_parts) + "</body></html>"
    return subject, text, body
