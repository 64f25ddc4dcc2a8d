// The component page's trend charts: grouped by case and phase, drawn when they come into view,
// a mark's click opens its regression, the hovered revision's commit and time shown below the
// filters. The data is the page's own <script type="application/json" id="trend-data">.
(function () {
  "use strict";
  const data = JSON.parse(document.getElementById("trend-data").textContent);
  const titles = data.revisions.map((r) => r[0]);
  const about = Object.fromEntries(data.revisions.map((r) => [r[0], r]));
  const holder = document.getElementById("charts");
  const info = document.getElementById("hover-info");

  if (!data.charts.length) {
    holder.textContent = "No results for this view yet.";
    return;
  }

  function draw(element, chart) {
    const traces = chart.figure.data.map((t) => (t.x ? t : Object.assign({}, t, { x: titles })));
    Plotly.newPlot(element, traces, chart.figure.layout, {
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
  }

  const pending = new Map();
  const observer = new IntersectionObserver((entries) => {
    for (const entry of entries) {
      if (entry.isIntersecting && pending.has(entry.target)) {
        draw(entry.target, pending.get(entry.target));
        pending.delete(entry.target);
        observer.unobserve(entry.target);
      }
    }
  }, { rootMargin: "400px" });

  let group = null;
  for (const chart of data.charts) {
    const heading = `${chart.case} / ${chart.phase}`;
    if (heading !== group) {
      group = heading;
      const h3 = document.createElement("h3");
      h3.textContent = heading;
      holder.appendChild(h3);
    }
    const element = document.createElement("div");
    element.className = "chart";
    element.id = chart.id;
    element.setAttribute("aria-label", chart.title);
    holder.appendChild(element);
    pending.set(element, chart);
    observer.observe(element);
  }
})();
