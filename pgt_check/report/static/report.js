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
  const DISAGREE = ci.disagree;
  const INSPECT_PAGE = 6;
  const FLICKER_MS = 500;
  const WIDE = { diff: true, arrows_raw: true, arrows_enhanced: true };
  const state = { sortKey: null, sortDir: 1, verdict: "", text: "", page: 0,
                  pageSize: data.page_size || 100, open: null, inspectPage: 0, allCols: false };
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
    if (c.type === "flag") { return v ? "\u2260" : ""; }
    return String(v);
  }

  function shownCols() {
    return cols.filter(function (c) { return state.allCols || !c.hidden; });
  }

  function isDisagree(i) { return DISAGREE !== undefined && rows[i][DISAGREE] === true; }

  function renderHead() {
    const tr = document.querySelector("#frame-table thead tr");
    tr.textContent = "";
    shownCols().forEach(function (c) {
      const th = el("th", { "data-key": c.key, title: c.key }, c.label);
      if (c.key === state.sortKey) { th.classList.add(state.sortDir > 0 ? "asc" : "desc"); }
      th.addEventListener("click", function () {
        if (state.sortKey === c.key) { state.sortDir = -state.sortDir; } else { state.sortKey = c.key; state.sortDir = 1; }
        state.page = 0;
        applyView();
      });
      tr.appendChild(th);
    });
  }

  // ---- full-size panels: a lightbox, with render/photo flicker where both exist -------------
  const lb = { box: document.getElementById("lightbox"), timer: null, pair: null, which: 0, caption: "" };
  lb.img = lb.box.querySelector("img");
  lb.cap = lb.box.querySelector("figcaption");

  function lbShow(src, caption, pair) {
    lbStop();
    lb.pair = pair;
    lb.caption = caption;
    lb.which = 0;
    lb.img.src = src;
    lb.cap.textContent = caption;
    lb.box.hidden = false;
  }
  function lbFlip() {
    if (!lb.pair) { return; }
    lb.which = 1 - lb.which;
    lb.img.src = lb.pair[lb.which];
    lb.cap.textContent = (lb.which ? "photo" : "render") + " (flicker; F stops)";
  }
  function lbStop() { if (lb.timer) { clearInterval(lb.timer); lb.timer = null; } }
  function lbClose() { lbStop(); lb.box.hidden = true; lb.img.removeAttribute("src"); }
  lb.box.addEventListener("click", lbClose);
  document.addEventListener("keydown", function (e) {
    if (lb.box.hidden) { return; }
    if (e.key === "Escape") { lbClose(); }
    if ((e.key === "f" || e.key === "F") && lb.pair) {
      if (lb.timer) { lbStop(); } else { lb.timer = setInterval(lbFlip, FLICKER_MS); }
    }
  });

  function flickerFigure(assets) {
    // render and photo in one place, swapped by a button or automatically
    const f = el("figure", { class: "flicker" });
    const img = el("img", { loading: "lazy", alt: "render / photo flicker" });
    const srcs = [assets.render, assets.photo];
    let which = 0, timer = null;
    img.src = srcs[0];
    const cap = el("figcaption", null, "render");
    function show(k) { which = k; img.src = srcs[k]; cap.textContent = k ? "photo" : "render"; }
    const swap = el("button", { type: "button", "data-act": "swap" }, "render \u21c4 photo");
    const auto = el("button", { type: "button", "data-act": "flicker" }, "\u25b6 flicker");
    swap.addEventListener("click", function (e) { e.stopPropagation(); show(1 - which); });
    auto.addEventListener("click", function (e) {
      e.stopPropagation();
      if (timer) { clearInterval(timer); timer = null; auto.textContent = "\u25b6 flicker"; return; }
      timer = setInterval(function () {
        if (!img.isConnected) { clearInterval(timer); timer = null; return; }
        show(1 - which);
      }, FLICKER_MS);
      auto.textContent = "\u25a0 stop";
    });
    img.addEventListener("click", function (e) {
      e.stopPropagation();
      lbShow(srcs[which], "render / photo (press F to flicker)", srcs);
    });
    f.appendChild(img);
    const bar = el("div", { class: "fbar" });
    bar.appendChild(swap);
    bar.appendChild(auto);
    f.appendChild(bar);
    f.appendChild(cap);
    return f;
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
    const h = el("h3", null, "frame " + fid + " \u2014 " + rows[i][VERDICT]);
    if (isDisagree(i)) {
      h.appendChild(el("span", { class: "badge disagree", title: "raw and enhanced paths fall on different sides of the threshold" },
                       "raw \u2260 enhanced"));
    }
    if (ci.evidence !== undefined && rows[i][ci.evidence]) {
      h.appendChild(el("span", { class: "badge evidence" }, "evidence: " + rows[i][ci.evidence]));
    }
    d.appendChild(h);
    d.appendChild(numbersBlock(i));
    const extra = data.extra[fid];
    const assets = data.assets[fid];
    if (assets) {
      const imgs = el("div", { class: "imgs" });
      const pair = assets.render && assets.photo ? [assets.render, assets.photo] : null;
      data.kinds.forEach(function (kind) {
        if (!assets[kind]) { return; }
        const f = el("figure", WIDE[kind] ? { class: "wide", "data-kind": kind } : { "data-kind": kind });
        const img = el("img", { loading: "lazy", alt: kind, title: "click: full size" });
        img.src = assets[kind];
        const label = data.kind_labels[kind] || kind;
        img.addEventListener("click", function (e) {
          e.stopPropagation();
          lbShow(assets[kind], label + " \u2014 frame " + fid, kind === "render" || kind === "photo" ? pair : null);
        });
        f.appendChild(img);
        f.appendChild(el("figcaption", null, label));
        imgs.appendChild(f);
        if (kind === "photo" && pair) { imgs.appendChild(flickerFigure(assets)); }
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
      const tr = el("tr", { class: "row" + (data.assets[fid] ? " has-assets" : "") + (isDisagree(i) ? " disagree" : ""),
                            "data-row": String(i) });
      shownCols().forEach(function (c) {
        const v = r[ci[c.key]];
        const cls = c.type === "verdict" ? "v-" + v : (c.type === "num" || c.type === "int" ? "num" : (c.type === "flag" ? "flag" : ""));
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
    renderHead();
  }

  function detailRow(i) {
    const tr = el("tr", { class: "detail-row" });
    const td = el("td", { colspan: String(shownCols().length) });
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

  document.getElementById("f-allcols").addEventListener("change", function (e) {
    state.allCols = e.target.checked; renderTable();
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
      const wrap = document.querySelector(".tablewrap");
      out.table_overflow_px = wrap.scrollWidth - wrap.clientWidth;
      out.window_width = window.innerWidth;
      const nHead = document.querySelectorAll("#frame-table th").length;
      const all = document.getElementById("f-allcols");
      all.checked = true;
      all.dispatchEvent(new Event("change"));
      out.n_cols_default = nHead;
      out.n_cols_all = document.querySelectorAll("#frame-table th").length;
      check("all_columns", out.n_cols_all === cols.length && (nHead < cols.length || !cols.some(function (c) { return c.hidden; })));
      all.checked = false;
      all.dispatchEvent(new Event("change"));
      out.n_disagree_rows = rows.filter(function (_, i) { return isDisagree(i); }).length;
      out.n_disagree_badges = document.querySelectorAll("#inspect-list .badge.disagree").length;
      const panel = document.querySelector('#inspect-list figure[data-kind] img');
      if (panel) {
        panel.click();
        check("lightbox_opens", !lb.box.hidden && lb.img.getAttribute("src") === panel.getAttribute("src"));
        document.dispatchEvent(new KeyboardEvent("keydown", { key: "Escape" }));
        check("lightbox_closes", lb.box.hidden);
      }
      const fl = document.querySelector("#inspect-list figure.flicker");
      if (fl) {
        const before = fl.querySelector("img").getAttribute("src");
        fl.querySelector('button[data-act="swap"]').click();
        check("flicker_swaps", fl.querySelector("img").getAttribute("src") !== before);
        out.flicker = true;
      }
      const imgs = Array.from(document.images).filter(function (im) { return im.getAttribute("src"); });
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
