"""Every page in Debian's Chromium (Playwright), against a real server on real Postgres holding a
judged history: no console error and no request to another host on any page (the settings pages
signed in), charts with their traces (the trend chart's by name), filters that change the address
and the charts, triage done in the page and stored (and refused with a wrong form token), and
every control of every page reachable with the keyboard.

With ``REDLINE_SCREENSHOTS=DIR`` it saves screenshots of the regression page (signed out, and
signed in with its triage form), the sign-in page and the settings page there, which the demo has
none of (docs/ui.md: the other pages' are of the demo, by test_end_to_end).
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from redline.server.db import migrate, session_factory
from redline.server.models import Revision
from redline.server.services.signin import create_user
from sqlalchemy import update

from tests.support.pages import Watched, chromium, emptied, history
from tests.support.servers import Services, fresh_database, live_server

PASSWORD = "correct horse battery"
#: the pages whose screenshots (REDLINE_SCREENSHOTS) are taken here rather than of the demo (the
#: regression page's signed out and in, and the settings', are taken by the tests that sign in)
ONLY_HERE = ("signin",)


@pytest.fixture(scope="module")
def site(services: Services, tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, str]]:
    """A running server over a judged history of 'builder' (a tenfold CPU change at r4): its
    address and the database's."""
    database_url, _ = fresh_database(services.database_url)
    migrate(database_url)
    tmp = tmp_path_factory.mktemp("browser")
    settings = emptied(services, database_url, tmp)
    history(database_url, tmp, [20.0, 20.0, 20.0, 200.0, 200.0, 200.0])
    with session_factory(database_url)() as session:
        create_user(session, "ada", PASSWORD, "admin")
    with live_server(settings) as url:
        yield url, database_url


@pytest.fixture(scope="module")
def browser() -> Iterator[object]:
    with chromium() as launched:
        yield launched


def _ids(site: tuple[str, str]) -> tuple[int, int, int]:
    """A regression's, one of its detections' and an execution's ids."""
    import httpx

    base = f"{site[0]}/api/v1/components/builder"
    regression = httpx.get(f"{base}/regressions").json()[0]
    detail = httpx.get(f"{base}/regressions/{regression['id']}").json()
    revision = httpx.get(f"{base}/revisions/r4").json()
    return regression["id"], detail["flagged"][0]["id"], revision["jobs"][0]["execution"]["id"]


def _pages(site: tuple[str, str]) -> dict[str, str]:
    """Every page's address, by name; those after "signin" need an administrator's sign-in."""
    regression, detection, execution = _ids(site)
    return {
        "home": "/",
        "component": "/components/builder",
        "executions": "/components/builder/executions",
        "revision": "/components/builder/revisions/r4",
        "compare": "/components/builder/compare?base=r1..r3&candidate=r4",
        "regressions": "/regressions",
        "regression": f"/regressions/{regression}",
        "why-flagged": f"/detections/{detection}",
        "execution": f"/executions/{execution}",
        "signin": "/signin",
        "settings": "/settings",
        "component-settings": "/settings/components/builder",
    }


SIGNED_IN = ("settings", "component-settings")


def test_every_page_loads_clean_with_its_charts(site, browser):
    base = site[0]
    watched = Watched(browser, base)
    pages = {k: v for k, v in _pages(site).items() if k not in SIGNED_IN}
    for name, path in pages.items():
        # docs/ui.md shows the demo's pages (test_end_to_end); the demo raises no regression
        watched.visit(base + path, name if name in ONLY_HERE else None)
        if name in ("component", "compare", "why-flagged", "execution"):
            assert watched.first_chart_traces() > 0, name
    assert not watched.errors, watched.errors
    assert not watched.foreign, watched.foreign


def test_series_labels_wrap_between_words_not_letter_by_letter(site, browser):
    """Left to the table's layout, the revision page's labels were squeezed to a few letters a
    line ("legs_and_rat / e/steady[leg / s=8,rate=1 / 0]"), the demo's page 15,800 px high."""
    watched = Watched(browser, site[0])
    watched.page.set_viewport_size({"width": 900, "height": 800})
    watched.visit(site[0] + "/components/builder/revisions/r4")
    widths = watched.page.evaluate(
        """() => Array.from(document.querySelectorAll('#detections td.label'))
               .map(td => [td.textContent, td.getBoundingClientRect().width])"""
    )
    rem = watched.page.evaluate("parseFloat(getComputedStyle(document.documentElement).fontSize)")
    assert widths and all(width >= 16 * rem - 1 for _, width in widths), widths
    assert not watched.errors, watched.errors


def test_each_verdict_links_to_why_in_view_on_a_narrower_page(site, browser):
    """The verdict table's "why" links were its last column, off to the right of a 1,400 px
    page behind the table's own scroll (the demo's labels): the verdict itself links there now.
    This history's labels are shorter, so its table overflows at 1,000 px (the last column's
    links at 1,323 px)."""
    watched = Watched(browser, site[0])
    watched.page.set_viewport_size({"width": 1000, "height": 900})
    watched.visit(site[0] + "/components/builder/revisions/r4")
    rights = watched.page.evaluate(
        """() => Array.from(document.querySelectorAll('#detections a[href^="/detections/"]'))
               .map(a => a.getBoundingClientRect().right)"""
    )
    assert rights and max(rights) <= 1000 - 16, rights  # left of a scroll bar, in view
    assert not watched.errors, watched.errors


def test_the_settings_pages_load_clean_signed_in(site, browser):
    base = site[0]
    watched = Watched(browser, base)
    watched.sign_in(base, "ada", PASSWORD)
    watched.visit(f"{base}/settings", "settings")
    listed = watched.page.locator("#settings-components a[href='/settings/components/builder']")
    assert listed.count() == 1
    watched.visit(f"{base}/settings/components/builder")
    assert watched.page.locator("textarea[name=config]").count() == 1
    assert not watched.errors, watched.errors
    assert not watched.foreign, watched.foreign


def test_the_trend_chart_has_its_mean_band_and_change_marks(site, browser):
    import httpx

    base = site[0]
    regression = httpx.get(f"{base}/api/v1/components/builder/regressions").json()[0]
    watched = Watched(browser, base)
    watched.visit(f"{base}/components/builder?counter=cpu&process=builder")
    watched.page.wait_for_selector(".js-plotly-plot .scatterlayer .trace", state="attached")
    title, names = watched.page.evaluate(
        """() => { const el = document.querySelector('.js-plotly-plot');
                   return [el.layout.title.text, el.data.map(t => t.name || '')]; }"""
    )
    assert title == "build/steady builder.cpu"
    for legs in ("legs=2", "legs=8"):  # each parameter set's mean and its band of one std
        assert {legs, f"{legs}: mean + std", f"{legs}: mean - std"} <= set(names), names
    mark = f"change ({regression['confirmation'].replace('_', ' ')})"
    assert mark in names, names
    flagged = watched.page.evaluate(
        f"() => document.querySelector('.js-plotly-plot').data.find(t => t.name === '{mark}').x"
    )
    assert set(flagged) == {regression["bad_revision"]}, flagged
    assert not watched.errors, watched.errors


def test_the_first_chart_is_drawn_at_once_the_others_as_they_come_into_view(site, browser):
    """A longer history lists more regressions above the charts: at 1,000 revisions the first
    chart sat past the fold and its margin, and was never drawn until scrolled to."""
    base = site[0]
    watched = Watched(browser, base)
    watched.page.set_viewport_size({"width": 1280, "height": 40})  # every chart below the fold
    watched.visit(f"{base}/components/builder")
    watched.page.wait_for_selector("#chart-1.js-plotly-plot .scatterlayer .trace", state="attached")
    charts = watched.page.locator("#charts .chart")
    assert charts.count() > 1 and charts.last.evaluate("el => el.data === undefined")
    charts.last.scroll_into_view_if_needed()
    watched.page.wait_for_function("el => el.data !== undefined", arg=charts.last.element_handle())
    assert not watched.errors, watched.errors


def test_filters_change_the_address_and_the_charts(site, browser):
    base = site[0]
    watched = Watched(browser, base)
    watched.visit(f"{base}/components/builder")
    before = watched.page.locator("#charts .chart").count()
    watched.page.select_option("select[name=counter]", "cpu")
    watched.page.check("input[name=median]")
    watched.page.click("#filters button[type=submit]")
    watched.page.wait_for_load_state("networkidle")
    assert "counter=cpu" in watched.page.url and "median=1" in watched.page.url
    after = watched.page.locator("#charts .chart").count()
    assert 0 < after < before
    watched.page.wait_for_selector(".js-plotly-plot .scatterlayer .trace", state="attached")
    names = watched.page.evaluate(
        "() => document.querySelector('.js-plotly-plot').data.map(t => t.name || '')"
    )
    assert any("moving median" in name for name in names), names
    assert not watched.errors, watched.errors


def test_panning_past_the_oldest_revision_loads_the_earlier_ones(site, browser):
    base = site[0]
    watched = Watched(browser, base)
    watched.visit(f"{base}/components/builder?counter=cpu&revisions=3")
    chart = watched.page.locator(".js-plotly-plot").first
    chart.locator(".scatterlayer .trace").first.wait_for(state="attached")
    first = "() => document.querySelector('.js-plotly-plot')"
    shown = f"({first})().data.find(t => t.mode === 'lines+markers').x"
    assert watched.page.evaluate(f"() => {shown}") == ["r4", "r5", "r6"]
    assert watched.page.locator("#earlier").count() == 1

    chart.hover()  # the mode bar shows on hover: pan, then drag the history to the right
    chart.locator('.modebar-btn[data-val="pan"]').click()
    area = chart.locator(".nsewdrag").first.bounding_box()
    assert area is not None
    middle_y = area["y"] + area["height"] / 2
    watched.page.mouse.move(area["x"] + area["width"] * 0.3, middle_y)
    watched.page.mouse.down()
    watched.page.mouse.move(area["x"] + area["width"] * 0.9, middle_y, steps=12)
    watched.page.mouse.up()

    watched.page.wait_for_function("() => location.search.includes('revisions=6')")
    watched.page.wait_for_function(f"() => {shown}.length === 6")
    assert watched.page.evaluate(f"() => {shown}") == [f"r{n}" for n in range(1, 7)]
    # the chart dragged keeps its place in the history: the blank it showed is now the older
    # revisions, not a jump back to the whole history
    left, right = watched.page.evaluate(f"() => ({first})().layout.xaxis.range")
    assert 0 <= left < 3 and right < 6, (left, right)
    assert watched.page.locator("#earlier").count() == 0  # nothing older is left
    assert watched.page.input_value("#filters input[name=revisions]") == "6"
    assert "3 earlier revisions loaded" in watched.page.inner_text("#hover-info")
    assert not watched.errors, watched.errors


def test_a_revision_title_with_markup_is_one_category_shown_as_text(site, browser):
    base, database_url = site
    title = "r5 & <i>x</i>"

    def rename(old: str, new: str) -> None:
        with session_factory(database_url)() as session:
            session.execute(update(Revision).where(Revision.title == old).values(title=new))
            session.commit()

    rename("r5", title)
    try:
        watched = Watched(browser, base)
        watched.visit(f"{base}/components/builder?counter=cpu&revisions=4")
        chart = watched.page.locator(".js-plotly-plot").first
        chart.locator(".scatterlayer .trace").first.wait_for(state="attached")
        x, categories = watched.page.evaluate(
            """() => { const el = document.querySelector('.js-plotly-plot');
                       return [el.data.find(t => t.mode === 'lines+markers').x,
                               el.layout.xaxis.categoryarray]; }"""
        )
        # the points sit on the axis's own categories: none is added after the newest
        assert x == categories and len(categories) == 4, (x, categories)
        ticks = chart.evaluate(
            "el => [...el.querySelectorAll('.xtick text')].map(t => t.textContent)"
        )
        assert title in ticks, ticks  # the markup shown as text, not made italic
        assert chart.locator(".xtick text tspan").count() == 0
        assert not watched.errors, watched.errors
    finally:
        rename(title, "r5")


def test_triage_in_the_page_is_stored_and_needs_a_sign_in(site, browser):
    import httpx

    base = site[0]
    regression, _, _ = _ids(site)
    watched = Watched(browser, base)
    watched.visit(f"{base}/regressions/{regression}", "regression-signed-out")
    assert watched.page.locator("#triage").count() == 0
    watched.page.click("text=Sign in")
    watched.page.fill("input[name=name]", "ada")
    watched.page.fill("input[name=password]", PASSWORD)
    watched.page.click("form.signin button[type=submit]")
    watched.page.wait_for_url(f"**/regressions/{regression}")
    assert watched.page.locator("#triage").count() == 1
    watched.shot("regression")  # signed in: with the triage form
    watched.page.check("input[name=state][value=acknowledged]")
    watched.page.fill("input[name=comment]", "looking at it")
    watched.page.click("#triage button[type=submit]")
    watched.page.wait_for_load_state("networkidle")
    stored = httpx.get(f"{base}/api/v1/components/builder/regressions/{regression}").json()
    assert stored["state"] == "acknowledged"
    assert stored["history"][-1]["who"] == "ada"
    assert "looking at it" in watched.page.content()
    assert not watched.errors, watched.errors


def test_a_triage_with_a_wrong_form_token_is_refused_in_the_browser(site, browser):
    import httpx

    base = site[0]
    regression, _, _ = _ids(site)
    address = f"{base}/api/v1/components/builder/regressions/{regression}"
    before = httpx.get(address).json()
    watched = Watched(browser, base)
    watched.sign_in(base, "ada", PASSWORD)
    watched.visit(f"{base}/regressions/{regression}")
    watched.page.evaluate(
        "() => { document.querySelector('#triage input[name=csrf]').value = 'x'; }"
    )
    state = "ignored" if before["state"] != "ignored" else "fixed"
    watched.page.check(f"input[name=state][value={state}]")
    with watched.page.expect_navigation() as answered:
        watched.page.click("#triage button[type=submit]")
    assert answered.value is not None and answered.value.status == 403
    assert "does not match this session" in watched.page.inner_text("main")
    after = httpx.get(address).json()
    assert (after["state"], len(after["history"])) == (before["state"], len(before["history"]))


@pytest.mark.parametrize(
    "name",
    ["home", "component", "executions", "revision", "compare", "regressions", "regression",
     "why-flagged", "execution", "signin", "settings", "component-settings"],
)  # fmt: skip
def test_keyboard_reaches_every_control(site, browser, name):
    base = site[0]
    path = _pages(site)[name]
    watched = Watched(browser, base)
    if name in SIGNED_IN:
        watched.sign_in(base, "ada", PASSWORD)
    watched.visit(base + path)
    # a group of radio buttons is one stop of the Tab key (arrows move within it)
    controls = watched.page.evaluate(
        """() => { const groups = new Set();
             return [...document.querySelectorAll(
               'a[href], button, select, input:not([type=hidden]), textarea')]
             .filter(el => el.offsetParent !== null && !el.disabled)
             .filter(el => el.type !== 'radio' || !groups.has(el.name) && groups.add(el.name))
             .map((el, i) => { el.dataset.control = i; return i; }); }"""
    )
    # Charts drawn after the count add their own stops (plotly's toolbar), so Tab on until
    # every counted control has had the focus, within a generous bound.
    reached: set[int] = set()
    for _ in range(4 * len(controls) + 50):
        watched.page.keyboard.press("Tab")
        found = watched.page.evaluate("() => document.activeElement.dataset.control")
        if found is not None:
            reached.add(int(found))
        if reached >= set(controls):
            break
    missed = sorted(set(controls) - reached)
    assert not missed, f"{path}: controls {missed} of {len(controls)} never got the focus"


def test_the_interactive_api_page_shows_every_call_without_the_internet(site, browser) -> None:
    """A new user's `/docs` was blank without the internet (FastAPI loads Swagger UI from a
    CDN); Swagger UI 4, served locally, cannot render the OpenAPI 3.1 document FastAPI makes
    (a reviewer's find). The page, in Chromium: the calls listed, nothing from another host."""
    watched = Watched(browser, site[0])
    watched.visit(f"{site[0]}/docs")
    watched.page.wait_for_selector(".opblock-summary-path", timeout=15_000)
    paths = watched.page.locator(".opblock-summary-path").all_inner_texts()
    assert "/api/v1/components" in [p.replace("\u200b", "") for p in paths], paths[:5]
    assert "Unable to render" not in watched.page.content()
    assert watched.foreign == [] and watched.errors == [], (watched.foreign, watched.errors)
