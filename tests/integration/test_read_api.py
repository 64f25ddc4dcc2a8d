"""The read API: paged revisions, series filters and points, executions, OpenAPI, /metrics."""

from __future__ import annotations

import base64
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.support.api import Api, api_with, commit_of
from tests.support.servers import Services


@pytest.fixture
def api(services: Services, tmp_path: Path) -> Iterator[Api]:
    with api_with(services, tmp_path) as api:
        api.component()  # a repository and a suite: CI reports its revisions too
        yield api


def imported(api: Api, revision: str, key: str) -> dict:
    body = {
        "component": "builder",
        "revision": revision,
        "sort_key": key,
        "results": [
            {
                "case": "build",
                "phase": "steady",
                "params": {"legs": legs},
                "process": proc,
                "counter": counter,
                "values": [float(legs), float(legs) + 1],
            }
            for legs in (4, 8)
            for proc in ("builder", "host")
            for counter in ("cpu", "rss")
        ],
    }
    answer = api.post("/api/v1/import/results", "admin", body)  # hosts measure 'builder'
    assert answer.status_code == 201, answer.text
    return answer.json()


def test_revisions_page_in_sort_key_order_with_a_cursor(api: Api):
    for title, key in (("r10", "10"), ("r9", "9"), ("r2", "2"), ("r11", "11"), ("r1", "1")):
        api.post(
            "/api/v1/revisions",
            "ci",
            {"component": "builder", "title": title, "sort_key": key, "commit": commit_of(title)},
        ).raise_for_status()
    seen, cursor, pages = [], None, 0
    while True:
        query = "?limit=2" + (f"&cursor={cursor}" if cursor else "")
        page = api.client.get(f"/api/v1/components/builder/revisions{query}")
        seen += [r["title"] for r in page.json()]
        pages += 1
        cursor = page.headers.get("x-next-cursor")
        if cursor is None:
            break
    assert seen == ["r1", "r2", "r9", "r10", "r11"] and pages == 3
    bad = api.client.get("/api/v1/components/builder/revisions?limit=2&cursor=@@@")
    assert bad.status_code == 400 and "cursor" in bad.json()["detail"]
    # an audit's: a cursor of JSON nested 1,200 deep was a 500, anonymously where reading is open
    nested = base64.urlsafe_b64encode(b"[" * 1200).decode()
    for path in (
        "/api/v1/components/builder/revisions",
        "/api/v1/components/builder/regressions",
        "/api/v1/components/builder/detections",
        "/regressions",
    ):
        deep = api.client.get(f"{path}?limit=2&cursor={nested}")
        assert deep.status_code == 400 and "malformed cursor" in deep.text, (path, deep.text[:200])


def test_series_filter_by_case_phase_parameter_process_and_counter(api: Api):
    imported(api, "r1", "1")
    url = "/api/v1/components/builder/series"
    assert len(api.client.get(url).json()) == 8
    chosen = api.client.get(
        f"{url}?param.legs=8&process=builder&counter=cpu&phase=steady&case=build"
    ).json()
    assert [(s["params"], s["process"], s["counter"]) for s in chosen] == [
        ({"legs": 8}, "builder", "cpu")
    ]
    assert api.client.get(f"{url}?param.legs=3").json() == []
    assert api.client.get(f"{url}?case=other").json() == []
    # the newest revisions only (an audit's: the whole history was read on every request)
    imported(api, "r2", "2")
    points = [[p["revision"] for p in s["points"]] for s in api.client.get(url).json()]
    assert points and all(p == ["r1", "r2"] for p in points), points
    newest = [
        [p["revision"] for p in s["points"]] for s in api.client.get(f"{url}?revisions=1").json()
    ]
    assert newest and all(p == ["r2"] for p in newest), newest
    assert api.client.get(f"{url}?revisions=0").status_code == 422


def test_series_points_carry_each_executions_quantiles_and_sketch(api: Api):
    imported(api, "r1", "1")
    imported(api, "r2", "2")
    series = api.client.get(
        "/api/v1/components/builder/series?param.legs=4&process=builder&counter=rss"
    ).json()[0]
    detail = api.client.get(f"/api/v1/series/{series['id']}").json()
    assert [s["revision"] for s in detail["summaries"]] == ["r1", "r2"]
    first = detail["summaries"][0]
    assert (first["min"], first["p50"], first["max"]) == (4.0, 4.5, 5.0)
    assert len(first["sketch"]) == 32 and first["sketch"] == sorted(first["sketch"])
    assert api.client.get("/api/v1/series/999999").status_code == 404


def test_execution_details_and_unknown_execution(api: Api):
    execution_id = imported(api, "r1", "1")["execution_id"]
    detail = api.client.get(f"/api/v1/executions/{execution_id}").json()
    assert (detail["component"], detail["revision"], detail["series"]) == ("builder", "r1", 8)
    assert detail["recording_pruned_at"] is None
    assert api.client.get("/api/v1/executions/999999").status_code == 404


def test_detections_of_an_unknown_revision_are_404_naming_it_not_an_empty_list(api: Api):
    """A trial's `?revision=nosuch` (a typo) answered 200 [], as if it had no verdict."""
    api.revision("r1", "1")
    listed = api.client.get("/api/v1/components/builder/detections?revision=r1")
    assert listed.status_code == 200 and listed.json() == []  # known, not judged yet
    unknown = api.client.get("/api/v1/components/builder/detections?revision=nosuch")
    assert unknown.status_code == 404
    assert unknown.json() == {"detail": "component 'builder' has no revision 'nosuch'"}
    compared = api.client.get("/api/v1/components/builder/compare?base=r1&candidate=nosuch")
    assert compared.json() == unknown.json()  # as compare says it


def test_openapi_gives_every_route_a_response_model(api: Api):
    document = api.client.get("/openapi.json").json()
    missing = []
    for path, operations in document["paths"].items():
        for method, operation in operations.items():
            ok = [code for code in operation["responses"] if code.startswith("2")]
            if not any("content" in operation["responses"][code] or code == "204" for code in ok):
                missing.append(f"{method.upper()} {path}")
    assert missing == []
    for path in (
        "/api/v1/webhooks/github",
        "/api/v1/import/lnt",
        "/api/v1/tokens",
        "/api/v1/components/{name}/compare",
        "/api/v1/series/{series_id}",
    ):
        assert path in document["paths"]


#: calls whose JSON body another system writes, read for the fields Redline needs only
FOREIGN_BODIES = {"/api/v1/webhooks/github", "/api/v1/webhooks/gitlab", "/api/v1/import/lnt"}


def test_the_interactive_api_page_loads_nothing_from_the_internet(api: Api):
    """A new user's `/docs` was blank in a lab without the internet: FastAPI's page loads
    Swagger UI from a CDN. Redline serves those files itself."""
    page = api.client.get("/docs")
    assert page.status_code == 200 and "/openapi.json" in page.text
    sources = re.findall(r'(?:src|href)="([^"]+)"', page.text)
    assert sources and all(source.startswith("/") for source in sources), sources
    for source in sources:
        served = api.client.get(source)
        assert served.status_code == 200 and len(served.content) > 500, source
    assert api.client.get("/redoc").status_code == 404  # FastAPI's other page, from a CDN too


def test_every_json_body_refuses_a_field_it_does_not_know(api: Api):
    """docs/api.md: a field a call does not know is refused, never ignored (a trial's triage,
    and an agent's heartbeat and fail, took a stray field)."""
    document = api.client.get("/openapi.json").json()
    schemas = document["components"]["schemas"]
    lax = []
    for path, operations in document["paths"].items():
        for method, operation in operations.items():
            body = operation.get("requestBody", {}).get("content", {}).get("application/json")
            if body is None or path in FOREIGN_BODIES:
                continue
            name = body["schema"]["$ref"].rsplit("/", 1)[-1]
            if schemas[name].get("additionalProperties") is not False:
                lax.append(f"{method.upper()} {path} ({name})")
    assert lax == []  # tests/integration/test_api.py sends some of them a stray field


def test_metrics_count_requests_and_jobs_by_state(api: Api):
    api.post(
        "/api/v1/revisions",
        "ci",
        {"component": "builder", "title": "r1", "sort_key": "1", "commit": "abc1234"},
    ).raise_for_status()
    api.client.get("/api/v1/components")
    text = api.client.get("/metrics").text
    assert 'redline_jobs{state="queued"} 1.0' in text
    assert 'route="/api/v1/components",status="200"' in text
    assert "redline_http_request_seconds_bucket" in text


def test_requests_of_unknown_methods_are_counted_as_one_other_method(api: Api):
    """A review: the HTTP server takes any token as a method, and each was a label set of its
    own: 200 requests of made-up methods, no token needed, grew /metrics to 8 MB."""
    before = len(api.client.get("/metrics").text)
    for number in range(50):
        answer = api.client.request(f"X{number:04d}" + "A" * 200, "/healthz")
        assert answer.status_code == 405
    text = api.client.get("/metrics").text
    assert "X0000" not in text and 'method="other",route="/healthz",status="405"' in text
    assert len(text) < before + 5_000, len(text) - before
