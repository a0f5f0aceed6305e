// slipdaq report: the page's script (written beside index.html as slipdaq-report.js, after plotly.min.js).
// A plot's container carries data-slipdaq-plot (its name) and data-slipdaq-src (the script beside the page that
// holds its figure, loaded once, when the first of its plots comes near the view: a page of many logs stays light).
// Containers with the same data-slipdaq-link share their time axis: a zoom in one moves the others.
// Tables with data-slipdaq-table sort by a click on a heading; a click on a row goes to its data-href.
(function () {
  "use strict";
  var figures = {};
  var scripts = {};
  var ranges = {};
  var config = { responsive: true, displaylogo: false };

  window.slipdaqReport = {
    add: function (figs) {
      Object.keys(figs).forEach(function (name) { figures[name] = figs[name]; });
    }
  };

  function load(src) {
    if (!scripts[src]) {
      scripts[src] = new Promise(function (resolve, reject) {
        var s = document.createElement("script");
        s.src = src;
        s.onload = resolve;
        s.onerror = function () { reject(new Error("slipdaq report: cannot load " + src)); };
        document.head.appendChild(s);
      });
    }
    return scripts[src];
  }

  function same(a, b) { return JSON.stringify(a) === JSON.stringify(b); }

  function xUpdate(ev) {
    if (ev["xaxis.autorange"]) { return { "xaxis.autorange": true }; }
    if ("xaxis.range[0]" in ev) { return { "xaxis.range": [ev["xaxis.range[0]"], ev["xaxis.range[1]"]] }; }
    if (ev["xaxis.range"]) { return { "xaxis.range": ev["xaxis.range"].slice() }; }
    return null;
  }

  function linked(el) {
    var group = el.getAttribute("data-slipdaq-link");
    if (!group) { return; }
    el.on("plotly_relayout", function (ev) {
      var upd = xUpdate(ev);
      if (!upd || same(upd, ranges[group])) { return; }
      ranges[group] = upd;
      document.querySelectorAll("[data-slipdaq-link]").forEach(function (other) {
        if (other !== el && other.getAttribute("data-slipdaq-link") === group &&
            other.getAttribute("data-state") === "rendered") {
          Plotly.relayout(other, upd);
        }
      });
    });
    if (ranges[group]) { Plotly.relayout(el, ranges[group]); }
  }

  function render(el) {
    if (el.getAttribute("data-state")) { return; }
    el.setAttribute("data-state", "loading");
    var name = el.getAttribute("data-slipdaq-plot");
    load(el.getAttribute("data-slipdaq-src")).then(function () {
      var fig = figures[name];
      if (!fig) { throw new Error("slipdaq report: no figure " + name); }
      return Plotly.newPlot(el, fig.data, fig.layout, config);
    }).then(function () {
      el.setAttribute("data-state", "rendered");
      linked(el);
    }).catch(function (e) {
      el.setAttribute("data-state", "failed");
      el.textContent = String(e.message || e);
      console.error(e);
    });
  }

  function observe() {
    var boxes = document.querySelectorAll("[data-slipdaq-plot]");
    if (!("IntersectionObserver" in window)) { boxes.forEach(render); return; }
    var io = new IntersectionObserver(function (entries) {
      entries.forEach(function (e) {
        if (e.isIntersecting) { io.unobserve(e.target); render(e.target); }
      });
    }, { rootMargin: "400px 0px" });
    boxes.forEach(function (el) { io.observe(el); });
  }

  function cellValue(row, i, numeric) {
    var td = row.cells[i];
    if (!numeric) { return td.textContent.trim().toLowerCase(); }
    var v = td.getAttribute("data-v");
    return v === null ? null : parseFloat(v);
  }

  function sortable(table) {
    var heads = table.tHead.rows[0].cells;
    var body = table.tBodies[0];
    Array.prototype.forEach.call(heads, function (th, i) {
      if (!th.hasAttribute("data-sort")) { return; }
      th.tabIndex = 0;
      var sort = function () {
        var numeric = th.getAttribute("data-sort") === "num";
        var dir = th.getAttribute("aria-sort") === "ascending" ? -1 : 1;
        Array.prototype.forEach.call(heads, function (h) { h.removeAttribute("aria-sort"); });
        th.setAttribute("aria-sort", dir === 1 ? "ascending" : "descending");
        var rows = Array.prototype.slice.call(body.rows);
        rows.sort(function (a, b) {
          var x = cellValue(a, i, numeric), y = cellValue(b, i, numeric);
          if (x === y) { return 0; }
          if (x === null) { return 1; }
          if (y === null) { return -1; }
          return (x < y ? -1 : 1) * dir;
        });
        rows.forEach(function (r) { body.appendChild(r); });
      };
      th.addEventListener("click", sort);
      th.addEventListener("keydown", function (ev) { if (ev.key === "Enter") { sort(); } });
    });
    body.addEventListener("click", function (ev) {
      if (ev.target.closest("a")) { return; }
      var tr = ev.target.closest("tr[data-href]");
      if (tr) { window.location.hash = tr.getAttribute("data-href"); }
    });
  }

  document.querySelectorAll("table[data-slipdaq-table]").forEach(sortable);
  observe();
})();
