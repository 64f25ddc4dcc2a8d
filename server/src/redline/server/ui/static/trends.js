// The component page's trend charts: grouped by case and phase, the first drawn at once (the
// regressions listed above it push it below the fold on a longer history), the others when they
// come into view; a mark's click opens its regression, the hovered revision's commit and time
// shown below the filters. The data is the page's own
// <script type="application/json" id="trend-data">.
//
// Earlier history on zoom and pan: when a chart's x axis is moved past its oldest revision and
// older ones exist, the same view with twice as many revisions (at most data-most) is fetched
// from data-source (`/components/{name}/trends`), every chart is given the longer history, a
// chart the user moved keeps showing what it showed (its range shifted by the revisions added
// before its oldest, so the blank to the left fills in), and the address says how many revisions
// are shown. Charts are matched by their key (case, phase, process, counter).
(function () {
  "use strict";
  const holder = document.getElementById("charts");
  const info = document.getElementById("hover-info");
  const state = {
    page: JSON.parse(document.getElementById("trend-data").textContent),
    view: holder.dataset.view,
    revisions: Number(holder.dataset.revisions),
    most: Number(holder.dataset.most),
    earlier: holder.dataset.earlier,
    loading: false,
  };
  let titles = []; // the revisions' titles as the x axis's categories (plot text, escaped)
  let about = {}; // category -> [title, commit, time]
  const elements = new Map(); // a chart's key -> its element
  const headings = new Map(); // [case, phase] -> its heading
  const pending = new Map(); // an element not drawn yet -> its chart
  let made = 0;

  // The x categories are the charts' own (`categoryarray`: titles as plot text, so a title with
  // markup is one category, drawn as text); the hover shows the raw title, as text.
  function learn(page) {
    titles = page.charts.length ? page.charts[0].figure.layout.xaxis.categoryarray : [];
    about = Object.fromEntries(titles.map((category, i) => [category, page.revisions[i]]));
  }

  function traces(chart) {
    return chart.figure.data.map((t) => (t.x ? t : Object.assign({}, t, { x: titles })));
  }

  function draw(element, chart) {
    Plotly.newPlot(element, traces(chart), chart.figure.layout, {
      responsive: true,
      displaylogo: false,
      // nothing leaves the page for plotly's cloud; box and lasso select mean nothing on a trend
      modeBarButtonsToRemove: ["sendDataToCloud", "select2d", "lasso2d"],
    });
    element.on("plotly_hover", (event) => {
      const revision = about[event.points[0].x];
      if (revision) info.textContent = `${revision[0]} · commit ${revision[1]} · ${revision[2]}`;
    });
    element.on("plotly_click", (event) => {
      const point = event.points[0];
      if (point.data.name.startsWith("change") && Number.isInteger(point.customdata)) {
        window.location.href = `/regressions/${point.customdata}`;
      }
    });
    element.on("plotly_relayout", (event) => {
      const range = event["xaxis.range"] || [event["xaxis.range[0]"], event["xaxis.range[1]"]];
      // past the oldest revision's slot (-0.5 to 0.5): a zoom into the left edge is not a move
      if (typeof range[0] === "number" && range[0] < -0.5) loadEarlier();
    });
  }

  const observer = new IntersectionObserver((entries) => {
    for (const entry of entries) {
      if (entry.isIntersecting && pending.has(entry.target)) {
        draw(entry.target, pending.get(entry.target));
        pending.delete(entry.target);
        observer.unobserve(entry.target);
      }
    }
  }, { rootMargin: "400px" });

  function placeAfter(node, previous) {
    holder.insertBefore(node, previous ? previous.nextSibling : holder.firstChild);
    return node;
  }

  // Every chart in the page's order, under its case and phase: the elements already there are
  // kept (and given the new data), a chart only the new data has is put in its place, and one
  // the new data lacks is taken away. ``added``: revisions added before the oldest shown (null
  // when the history changed otherwise: the charts then show it all).
  function place(charts, added) {
    let eager = null; // the page's first chart: drawn at once, wherever the layout puts it
    let previous = null;
    let group = null;
    const wanted = new Set();
    for (const chart of charts) {
      const heading = JSON.stringify([chart.case, chart.phase]);
      if (heading !== group) {
        group = heading;
        if (!headings.has(heading)) {
          const h3 = document.createElement("h3");
          h3.textContent = `${chart.case} / ${chart.phase}`;
          headings.set(heading, h3);
        }
        wanted.add(headings.get(heading));
        previous = placeAfter(headings.get(heading), previous);
      }
      let element = elements.get(chart.key);
      if (!element) {
        element = document.createElement("div");
        element.className = "chart";
        element.id = `chart-${++made}`;
        element.setAttribute("aria-label", chart.title);
        elements.set(chart.key, element);
        if (made === 1) {
          eager = [element, chart];
        } else {
          pending.set(element, chart);
          observer.observe(element);
        }
      } else if (pending.has(element)) {
        pending.set(element, chart);
      } else {
        redraw(element, chart, added);
      }
      wanted.add(element);
      previous = placeAfter(element, previous);
    }
    for (const [key, node] of [...elements, ...headings]) {
      if (wanted.has(node)) continue;
      if (pending.delete(node)) observer.unobserve(node);
      else if (node.classList.contains("chart")) Plotly.purge(node);
      elements.delete(key);
      headings.delete(key);
      node.remove();
    }
    if (eager) draw(...eager);
  }

  // A drawn chart given a longer history: a range the user chose is kept on the same revisions.
  function redraw(element, chart, added) {
    const axis = element.layout.xaxis;
    const kept = added === null || axis.autorange ? null : axis.range;
    const layout = Object.assign({}, chart.figure.layout);
    if (kept) {
      layout.xaxis = Object.assign({}, layout.xaxis, {
        range: [kept[0] + added, kept[1] + added],
        autorange: false,
      });
    }
    Plotly.react(element, traces(chart), layout);
  }

  async function loadEarlier() {
    if (!state.earlier || state.loading) return;
    if (state.revisions >= state.most) {
      info.textContent = `A page shows at most ${state.most} revisions: "◀ earlier revisions" pages back.`;
      return;
    }
    state.loading = true;
    const wanted = Math.min(state.most, state.revisions * 2);
    const query = new URLSearchParams(state.view);
    query.set("revisions", String(wanted));
    const token = new URLSearchParams(window.location.search).get("token");
    if (token) query.set("token", token);
    info.textContent = "Loading earlier revisions…";
    try {
      const response = await fetch(`${holder.dataset.source}?${query}`, {
        headers: { Accept: "application/json" },
        credentials: "same-origin",
      });
      const json = (response.headers.get("content-type") || "").startsWith("application/json");
      const answer = json ? await response.json() : null;
      if (!response.ok || !answer) {
        throw new Error((answer && answer.detail) || `${response.status} ${response.statusText}`);
      }
      const oldest = titles[0];
      learn(answer.page);
      // where the oldest revision shown before now stands: the revisions added before it
      const at = titles.indexOf(oldest);
      const added = at >= 0 ? at : null;
      state.page = answer.page;
      state.view = answer.view;
      state.revisions = wanted;
      state.earlier = answer.earlier || "";
      place(answer.page.charts, added);
      const address = new URLSearchParams(answer.view);
      if (token) address.set("token", token);
      window.history.replaceState(null, "", `?${address}`);
      const field = document.querySelector("#filters input[name=revisions]");
      if (field) field.value = String(wanted);
      const link = document.getElementById("earlier");
      if (link && state.earlier) {
        const before = new URLSearchParams(answer.view);
        before.set("before", state.earlier);
        link.href = `?${before}`;
      } else if (link) {
        link.remove();
      }
      const newest = document.getElementById("newest");
      if (newest) {
        const latest = new URLSearchParams(answer.view);
        latest.delete("before");
        newest.href = `?${latest}`;
      }
      info.textContent = added
        ? `${added} earlier revisions loaded: ${titles.length} shown.`
        : `${titles.length} revisions shown.`;
    } catch (error) {
      info.textContent = `The earlier revisions could not be loaded: ${error.message}`;
    } finally {
      state.loading = false;
    }
  }

  learn(state.page);
  if (!state.page.charts.length) {
    holder.textContent = "No results for this view yet.";
    return;
  }
  place(state.page.charts, 0);
})();
