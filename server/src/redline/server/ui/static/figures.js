// Pages whose charts come whole from the server: <script type="application/json"
// id="figure-data"> holds a list of plotly figures, drawn one after another in #figures.
(function () {
  "use strict";
  const figures = JSON.parse(document.getElementById("figure-data").textContent);
  const holder = document.getElementById("figures");
  figures.forEach((figure, index) => {
    const element = document.createElement("div");
    element.className = "chart";
    element.id = `figure-${index + 1}`;
    holder.appendChild(element);
    Plotly.newPlot(element, figure.data, figure.layout, {
      responsive: true,
      displaylogo: false,
      // nothing leaves the page for plotly's cloud; box and lasso select mean nothing on a trend
      modeBarButtonsToRemove: ["sendDataToCloud", "select2d", "lasso2d"],
    });
  });
})();
