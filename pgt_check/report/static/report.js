// pgt-check report: frame table (sort, filter, paginate) and lazily built detail panels.
// All user data is inserted with textContent, never as HTML. No network access.
(function () {
  "use strict";
  const data = JSON.parse(document.getElementById("pgt-data").textContent);
  const cols = data.columns;
  const rows = data.rows;
  const ci = {};
  cols.forEach(function (c, i) { ci[c.key] = i; });
  const ID = ci.frame_id;
  const VERDICT = ci.verdict;
  const INSPECT_PAGE = 6;
  const state = { sortKey: null, sortDir: 1, verdict: "", text: "", page: 0,
                  pageSize: data.page_size || 100, open: null, inspectPage: 0 };
  let view = rows.map(function (_, i) { return i; });
  const byId = {};
  rows.forEach(function (r, i) { byId[String(r[ID])] = i; });
  // lower-cased text of each row, for the text filter (built once)
  const haystack = rows.map(function (r) {
    return cols.filter(function (c) { return c.type === "str" || c.type === "verdict"; })
      .map(function (c) { return r[ci[c.key]] == null ? "" : String(r[ci[c.key]]); })
      .join("\u0001").toLowerCase();
  });

  function el(tag, attrs, text) {
    const e = document.createElement(tag);
    if (attrs) {
      Object.keys(attrs).forEach(function (k) { e.setAttribute(k, attrs[k]); });
    }
    if (text !== undefined && text !== null) { e.textContent = text; }
    return e;
  }

  function fmt(v, c) {
    if (v === null || v === undefined || v === "") { return ""; }
    if (c.type === "num") {
      if (typeof v !== "number") { return String(v); }
      if (c.digits == null) { return Number.isInteger(v) ? String(v) : v.toFixed(3); }
      return v.toFixed(c.digits);
    }
    if (c.type === "bool") { return v ? "yes" : "no"; }
    return String(v);
  }

  function compare(a, b) {
    // nulls sort last in both directions
    const an = a === null || a === undefined || a === "";
    const bn = b === null || b === undefined || b === "";
    if (an || bn) { return an === bn ? 0 : (an ? 1 : -1) * state.sortDir; }
    if (typeof a === "number" && typeof b === "number") { return a - b; }
    const sa = String(a), sb = String(b);
    return sa < sb ? -1 : (sa > sb ? 1 : 0);
  }

  function applyView() {
    const text = state.text.toLowerCase();
    view = [];
    for (let i = 0; i < rows.length; i++) {
      if (state.verdict && rows[i][VERDICT] !== state.verdict) { continue; }
      if (text && haystack[i].indexOf(text) < 0) { continue; }
      view.push(i);
    }
    if (state.sortKey !== null) {
      const k = ci[state.sortKey];
      const dir = state.sortDir;
      view.sort(function (x, y) {
        const c = compare(rows[x][k], rows[y][k]);
        return (c === 0 ? x - y : c * dir);
      });
    }
    const nPages = Math.max(1, Math.ceil(view.length / state.pageSize));
    if (state.page >= nPages) { state.page = nPages - 1; }
    renderTable();
  }

  function numbersBlock(i) {
    const div = el("div", { class: "nums" });
    cols.forEach(function (c) {
      const v = rows[i][ci[c.key]];
      if (v === null || v === undefined || v === "") { return; }
      const s = el("span");
      s.appendChild(el("b", null, c.label + ": "));
      s.appendChild(document.createTextNode(fmt(v, c)));
      div.appendChild(s);
    });
    return div;
  }

  function buildDetail(i) {
    const fid = String(rows[i][ID]);
    const d = el("div", { class: "detail", "data-frame": fid });
    d.appendChild(el("h3", null, "frame " + fid + " \u2014 " + rows[i][VERDICT]));
    d.appendChild(numbersBlock(i));
    const extra = data.extra[fid];
    const assets = data.assets[fid];
    if (assets) {
      const imgs = el("div", { class: "imgs" });
      data.kinds.forEach(function (kind) {
        if (!assets[kind]) { return; }
        const f = el("figure", kind === "matches" ? { class: "wide" } : null);
        const img = el("img", { loading: "lazy", alt: kind });
        img.src = assets[kind];
        f.appendChild(img);
        f.appendChild(el("figcaption", null, data.kind_labels[kind] || kind));
        imgs.appendChild(f);
      });
      d.appendChild(imgs);
    } else {
      d.appendChild(el("div", { class: "muted" },
        "No images stored for this frame (images are kept only for the frames to inspect)."));
    }
    if (extra && extra.error_detail) { d.appendChild(el("pre", null, extra.error_detail)); }
    return d;
  }

  function pager(container, page, nPages, total, go) {
    container.textContent = "";
    const prev = el("button", { type: "button", "data-act": "prev" }, "\u2039 prev");
    const next = el("button", { type: "button", "data-act": "next" }, "next \u203A");
    prev.disabled = page <= 0;
    next.disabled = page >= nPages - 1;
    prev.addEventListener("click", function () { go(page - 1); });
    next.addEventListener("click", function () { go(page + 1); });
    container.appendChild(prev);
    container.appendChild(el("span", { class: "pageinfo" },
      "page " + (page + 1) + " / " + nPages + " (" + total + ")"));
    container.appendChild(next);
  }

  function renderTable() {
    const tbody = document.querySelector("#frame-table tbody");
    const frag = document.createDocumentFragment();
    const start = state.page * state.pageSize;
    const end = Math.min(view.length, start + state.pageSize);
    for (let p = start; p < end; p++) {
      const i = view[p];
      const r = rows[i];
      const fid = String(r[ID]);
      const tr = el("tr", { class: "row" + (data.assets[fid] ? " has-assets" : ""), "data-row": String(i) });
      cols.forEach(function (c) {
        const v = r[ci[c.key]];
        const cls = c.type === "verdict" ? "v-" + v : (c.type === "num" || c.type === "int" ? "num" : "");
        const td = el("td", cls ? { class: cls } : null, fmt(v, c));
        if (c.type === "str" && v) { td.title = String(v); }
        tr.appendChild(td);
      });
      tr.addEventListener("click", function () { toggleDetail(i, tr); });
      frag.appendChild(tr);
      if (state.open === i) { frag.appendChild(detailRow(i)); }
    }
    tbody.textContent = "";
    tbody.appendChild(frag);
    const nPages = Math.max(1, Math.ceil(view.length / state.pageSize));
    pager(document.getElementById("table-pager"), state.page, nPages, view.length,
          function (p) { state.page = p; renderTable(); });
    document.getElementById("f-count").textContent = view.length + " of " + rows.length + " frames";
    document.querySelectorAll("#frame-table th").forEach(function (th) {
      th.classList.remove("asc", "desc");
      if (th.dataset.key === state.sortKey) { th.classList.add(state.sortDir > 0 ? "asc" : "desc"); }
    });
  }

  function detailRow(i) {
    const tr = el("tr", { class: "detail-row" });
    const td = el("td", { colspan: String(cols.length) });
    td.appendChild(buildDetail(i));
    tr.appendChild(td);
    return tr;
  }

  function toggleDetail(i, tr) {
    const next = tr.nextElementSibling;
    if (next && next.classList.contains("detail-row")) { next.remove(); }
    if (state.open === i) { state.open = null; return; }
    const old = document.querySelector("#frame-table tr.detail-row");
    if (old) { old.remove(); }
    state.open = i;
    tr.after(detailRow(i));
  }

  function renderInspect() {
    const list = data.inspect.filter(function (fid) { return byId[fid] !== undefined; });
    const nPages = Math.max(1, Math.ceil(list.length / INSPECT_PAGE));
    const box = document.getElementById("inspect-list");
    box.textContent = "";
    if (!list.length) { box.appendChild(el("p", { class: "muted" }, "Nothing to inspect: every frame passed.")); }
    list.slice(state.inspectPage * INSPECT_PAGE, (state.inspectPage + 1) * INSPECT_PAGE)
      .forEach(function (fid) { box.appendChild(buildDetail(byId[fid])); });
    pager(document.getElementById("inspect-pager"), state.inspectPage, nPages, list.length,
          function (p) { state.inspectPage = p; renderInspect(); });
  }

  document.querySelectorAll("#frame-table th").forEach(function (th) {
    th.addEventListener("click", function () {
      const k = th.dataset.key;
      if (state.sortKey === k) { state.sortDir = -state.sortDir; } else { state.sortKey = k; state.sortDir = 1; }
      state.page = 0;
      applyView();
    });
  });
  document.getElementById("f-verdict").addEventListener("change", function (e) {
    state.verdict = e.target.value; state.page = 0; applyView();
  });
  document.getElementById("f-text").addEventListener("input", function (e) {
    state.text = e.target.value; state.page = 0; applyView();
  });
  document.getElementById("f-pagesize").addEventListener("change", function (e) {
    state.pageSize = parseInt(e.target.value, 10) || 100; state.page = 0; applyView();
  });

  applyView();
  renderInspect();

  // ---- self-test (used by the browser test): open report.html#selftest --------------------
  function selftest() {
    const out = { ok: true, checks: {}, errors: [] };
    function check(name, cond) { out.checks[name] = !!cond; if (!cond) { out.ok = false; } }
    function visible(key) {
      const k = cols.findIndex(function (c) { return c.key === key; });
      return Array.from(document.querySelectorAll("#frame-table tbody tr.row")).map(function (tr) {
        return rows[parseInt(tr.dataset.row, 10)][k];
      });
    }
    function sorted(vals, dir) {
      const v = vals.filter(function (x) { return x !== null && x !== ""; });
      for (let j = 1; j < v.length; j++) { if ((v[j] - v[j - 1]) * dir < 0) { return false; } }
      return true;
    }
    try {
      const nRows = document.querySelectorAll("#frame-table tbody tr.row").length;
      check("first_page_rows", nRows === Math.min(rows.length, state.pageSize));
      const th = document.querySelector('#frame-table th[data-key="corner_error_px"]');
      th.click();
      out.sorted_asc = visible("corner_error_px").slice(0, 5);
      check("sort_asc", sorted(visible("corner_error_px"), 1));
      th.click();
      out.sorted_desc = visible("corner_error_px").slice(0, 5);
      check("sort_desc", sorted(visible("corner_error_px"), -1));
      const sel = document.getElementById("f-verdict");
      sel.value = "FAIL";
      sel.dispatchEvent(new Event("change"));
      const vs = visible("verdict");
      out.n_fail_shown = view.length;
      check("filter_verdict", vs.every(function (v) { return v === "FAIL"; }));
      check("filter_count", view.length === rows.filter(function (r) { return r[VERDICT] === "FAIL"; }).length);
      sel.value = "";
      sel.dispatchEvent(new Event("change"));
      const probe = String(rows[rows.length - 1][ID]);
      const txt = document.getElementById("f-text");
      txt.value = probe;
      txt.dispatchEvent(new Event("input"));
      out.n_text_shown = view.length;
      check("filter_text", view.length >= 1 && visible("frame_id").some(function (v) { return String(v) === probe; }));
      txt.value = "";
      txt.dispatchEvent(new Event("input"));
      check("filter_cleared", view.length === rows.length);
      if (rows.length > state.pageSize) {
        document.querySelector('#table-pager button[data-act="next"]').click();
        check("page_next", state.page === 1);
      }
      const first = document.querySelector("#frame-table tbody tr.row");
      if (first) {
        first.click();
        check("detail_opens", !!document.querySelector("#frame-table tr.detail-row .detail"));
      }
      out.n_inspect_panels = document.querySelectorAll("#inspect-list .detail").length;
      const imgs = Array.from(document.images);
      out.n_images_loaded = imgs.filter(function (im) { return im.complete && im.naturalWidth > 0; }).length;
      out.broken_images = imgs.filter(function (im) { return im.complete && im.naturalWidth === 0; })
        .map(function (im) { return im.getAttribute("src"); });
      check("no_broken_images", out.broken_images.length === 0);
      out.n_rows = rows.length;
    } catch (err) {
      out.ok = false;
      out.errors.push(String(err && err.stack || err));
    }
    const pre = document.getElementById("selftest-result");
    pre.textContent = JSON.stringify(out);
    pre.dataset.ok = String(out.ok);
  }
  if (window.location.hash === "#selftest") { window.addEventListener("load", selftest); }
})();
