// Tables with class "sortable": a button in each header cell sorts by that column (again:
// the other way). Cells may carry the value to sort by in data-value.
(function () {
  "use strict";
  function key(cell) {
    const raw = cell.dataset.value !== undefined ? cell.dataset.value : cell.textContent.trim();
    const number = Number.parseFloat(raw);
    return Number.isNaN(number) ? raw.toLowerCase() : number;
  }
  for (const table of document.querySelectorAll("table.sortable")) {
    const headers = table.tHead.rows[0].cells;
    for (let column = 0; column < headers.length; column++) {
      const button = document.createElement("button");
      button.type = "button";
      button.className = "sort";
      button.textContent = headers[column].textContent;
      headers[column].textContent = "";
      headers[column].appendChild(button);
      let ascending = true;
      button.addEventListener("click", () => {
        const body = table.tBodies[0];
        const rows = [...body.rows].sort((a, b) => {
          const x = key(a.cells[column]);
          const y = key(b.cells[column]);
          const order = typeof x === typeof y ? (x < y ? -1 : x > y ? 1 : 0) : typeof x === "number" ? -1 : 1;
          return ascending ? order : -order;
        });
        for (const row of rows) body.appendChild(row);
        for (const cell of headers) cell.removeAttribute("aria-sort");
        headers[column].setAttribute("aria-sort", ascending ? "ascending" : "descending");
        ascending = !ascending;
      });
    }
  }
})();
