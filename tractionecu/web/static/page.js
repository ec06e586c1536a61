// tractionecu in-cab page: read-only; state pushed over /ws (the full state first, then updates).
"use strict";
(function () {
  const $ = (id) => document.getElementById(id);
  const fmt = (x, d) => (x === null || x === undefined || !isFinite(x)) ? "-" : Number(x).toFixed(d);
  const pct = (x, d) => (x === null || x === undefined || !isFinite(x)) ? "-" : (100 * x).toFixed(d) + " %";
  let updates = 0, last = null;
  // estimator status bits that are notices, not faults (estimation/estimator.py)
  const NOTICES = new Set(["measurement_gated", "covariance_repaired", "unverified_assumptions", "machine_level",
                           "rho_s_and_draft_not_separated"]);
  const map = { cell: 3, fields: ["a", "rho_s", "slip", "eta"], cells: new Map(), track: [] };

  function connect() {
    const ws = new WebSocket((location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws");
    ws.onopen = () => { $("conn").textContent = "live"; $("conn").className = "ok"; };
    ws.onclose = () => { $("conn").textContent = "reconnecting"; $("conn").className = "bad"; setTimeout(connect, 2000); };
    ws.onmessage = (ev) => { try { show(JSON.parse(ev.data)); } catch (e) { console.error(e); } };
  }

  function show(s) {
    updates += 1; last = s;
    $("updates").textContent = updates;
    $("t").textContent = fmt(s.t, 1);
    const e = s.estimate || {}, f = s.efficiency || {};
    $("v").textContent = fmt(e.v, 2);
    $("eta").textContent = fmt(f.eta, 3);
    $("eta-star").textContent = fmt(f.eta_star, 3);
    $("s-star").textContent = pct(f.s_star, 1);
    $("s-star-ci").textContent = (f.s_star_lo != null && f.s_star_hi != null) ? "95 %: " + pct(f.s_star_lo, 1) + " – " + pct(f.s_star_hi, 1) : "";
    $("slip").textContent = pct(f.slip, 1);
    $("bar-eta").style.width = (100 * Math.max(0, Math.min(1, f.eta || 0))) + "%";
    $("bar-eta-star").style.width = (100 * Math.max(0, Math.min(1, f.eta_star || 0))) + "%";
    $("eff-why").textContent = (f.reasons && f.reasons.length) ? "Not given: " + f.reasons.join(", ") :
      (f.eta_lost != null ? "efficiency lost against s*: " + fmt(f.eta_lost, 3) : "");
    const kN = (x) => (x === null || x === undefined) ? "-" : fmt(x / 1000, 1);
    $("pull").textContent = kN(f.pull_n);
    $("pull-star").textContent = kN(f.pull_at_s_star_n);
    $("eta-f").textContent = fmt(f.eta_front, 3);
    $("eta-r").textContent = fmt(f.eta_rear, 3);
    const rows = $("wheels").tBodies[0].rows;
    for (let i = 0; i < 4; i++) {
      rows[0].cells[i + 1].textContent = pct((e.slip || [])[i], 1);
      rows[1].cells[i + 1].textContent = fmt((e.mu || [])[i], 3);
      rows[2].cells[i + 1].textContent = fmt((f.eta_wheels || [])[i], 3);
    }
    $("rho").textContent = fmt(e.rho_s, 3);
    $("a").textContent = fmt(e.a, 3);
    $("cls").textContent = e.soil_class || "-";
    drawCurve(s);
    if (s.map) mergeMap(s.map);
    drawMap();
    showAdvice(s.advice || []);
    showHealth(s);
  }

  function axes(ctx, w, h, pad) {
    ctx.strokeStyle = "#555"; ctx.lineWidth = 1;
    ctx.strokeRect(pad, 5, w - pad - 5, h - pad - 5);
    ctx.fillStyle = "#999"; ctx.font = "11px sans-serif";
  }

  function drawCurve(s) {
    const cv = $("curve"), ctx = cv.getContext("2d"), W = cv.width, H = cv.height, P = 34;
    ctx.clearRect(0, 0, W, H);
    axes(ctx, W, H, P);
    const c = s.curve, e = s.estimate || {}, f = s.efficiency || {};
    const smax = c ? c.s[c.s.length - 1] : 0.3, ymax = 1.0;
    const X = (x) => P + (W - P - 5) * x / smax, Y = (y) => H - P - (H - P - 10) * y / ymax;
    for (let k = 0; k <= 6; k++) { const x = smax * k / 6; ctx.fillText((100 * x).toFixed(0) + "%", X(x) - 8, H - P + 14); }
    for (let k = 0; k <= 4; k++) { const y = ymax * k / 4; ctx.fillText(y.toFixed(2), 2, Y(y) + 4); }
    ctx.fillText("slip", W - 30, H - 4);
    $("curve-label").textContent = c ? c["class"] + ", a = " + fmt(c.a, 3) : "(curve not identified)";
    if (f.s_star_lo != null && f.s_star_hi != null) {
      ctx.fillStyle = "rgba(255,204,51,0.15)";
      ctx.fillRect(X(f.s_star_lo), 5, X(f.s_star_hi) - X(f.s_star_lo), H - P - 5);
    }
    if (f.s_star != null) {
      ctx.strokeStyle = "#fc3"; ctx.lineWidth = 2; ctx.beginPath();
      ctx.moveTo(X(f.s_star), 5); ctx.lineTo(X(f.s_star), H - P); ctx.stroke();
    }
    if (c) {
      line(ctx, c.s, c.mu, X, Y, "#6af", []);
      line(ctx, c.s, c.eta, X, Y, "#4c4", [5, 4]);
    }
    (e.slip || []).forEach((sl, i) => {
      const mu = (e.mu || [])[i];
      if (sl == null || mu == null) return;
      // reversing, slip and μ are both negative: the curve is the same, drawn for their sizes
      ctx.fillStyle = "#f84"; ctx.beginPath();
      ctx.arc(X(Math.min(Math.abs(sl), smax)), Y(Math.abs(mu)), 4, 0, 7); ctx.fill();
    });
  }

  function line(ctx, xs, ys, X, Y, color, dash) {
    ctx.strokeStyle = color; ctx.lineWidth = 2; ctx.setLineDash(dash); ctx.beginPath();
    let started = false;
    for (let i = 0; i < xs.length; i++) {
      if (ys[i] == null || ys[i] < -0.05) { started = false; continue; }
      if (!started) { ctx.moveTo(X(xs[i]), Y(ys[i])); started = true; } else ctx.lineTo(X(xs[i]), Y(ys[i]));
    }
    ctx.stroke(); ctx.setLineDash([]);
  }

  function mergeMap(m) {
    if (m.full) map.cells.clear();
    map.cell = m.cell_m; map.fields = m.fields;
    for (const c of m.cells) map.cells.set(c[0] + "," + c[1], c);
    if (m.full) map.track = m.track.slice(); else for (const p of m.track) {
      const q = map.track[map.track.length - 1];
      if (!q || q[0] !== p[0] || q[1] !== p[1]) map.track.push(p);
    }
    if (map.track.length > 4000) map.track.splice(0, map.track.length - 4000);
  }

  function drawMap() {
    const cv = $("map"), ctx = cv.getContext("2d"), W = cv.width, H = cv.height;
    ctx.clearRect(0, 0, W, H);
    const field = $("map-field").value, j = 2 + map.fields.indexOf(field);
    let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity, v0 = Infinity, v1 = -Infinity;
    for (const c of map.cells.values()) {
      x0 = Math.min(x0, c[0]); x1 = Math.max(x1, c[0] + 1); y0 = Math.min(y0, c[1]); y1 = Math.max(y1, c[1] + 1);
      if (c[j] != null) { v0 = Math.min(v0, c[j]); v1 = Math.max(v1, c[j]); }
    }
    if (!isFinite(x0)) { ctx.fillStyle = "#777"; ctx.fillText("no mapped position yet", 10, 20); return; }
    const k = Math.min((W - 10) / (x1 - x0), (H - 10) / (y1 - y0));
    const ox = (W - (x1 - x0) * k) / 2, oy = (H - (y1 - y0) * k) / 2;     // centred
    const X = (i) => ox + (i - x0) * k, Y = (i) => H - oy - (i - y0) * k;
    const span = (v1 - v0) || 1;
    for (const c of map.cells.values()) {
      if (c[j] == null) continue;
      const u = (c[j] - v0) / span;
      ctx.fillStyle = "hsl(" + (240 - 240 * u).toFixed(0) + ",80%,50%)";
      ctx.fillRect(X(c[0]), Y(c[1] + 1), Math.max(k, 1), Math.max(k, 1));
    }
    ctx.strokeStyle = "rgba(255,255,255,0.5)"; ctx.lineWidth = 1; ctx.beginPath();
    map.track.forEach((p, i) => { const px = X(p[0] / map.cell), py = Y(p[1] / map.cell); if (i) ctx.lineTo(px, py); else ctx.moveTo(px, py); });
    ctx.stroke();
    $("map-range").textContent = isFinite(v0) ? "blue " + fmt(v0, 3) + " … red " + fmt(v1, 3) + " · " + map.cells.size + " cells of " + map.cell + " m" : "";
  }

  function showAdvice(list) {
    const ul = $("advice");
    ul.textContent = "";
    if (!list.length) { const li = document.createElement("li"); li.className = "none"; li.textContent = "none"; ul.appendChild(li); return; }
    for (const r of list) {
      const li = document.createElement("li"); li.textContent = r.text;
      const d = document.createElement("details"), sm = document.createElement("summary");
      sm.textContent = "the numbers it rests on"; d.appendChild(sm);
      const pre = document.createElement("pre");
      pre.textContent = Object.entries(r.evidence).map(([k, v]) => k + " = " + (typeof v === "number" ? Number(v.toPrecision(4)) : v)).join("\n");
      d.appendChild(pre); li.appendChild(d); ul.appendChild(li);
    }
  }

  function showHealth(s) {
    const h = s.health || {}, e = s.estimate || {}, r = h.rates || {};
    const rows = [
      ["CAN", h.can, h.can === "open"], ["GNSS", h.gps, h.gps !== "down"],
      // before the first estimate there are no bits to show, not "none" in green
      s.estimate ? ["status bits", (e.status_bits || []).join(", ") || "none", (e.status_bits || []).every((b) => NOTICES.has(b))]
                 : ["status bits", "no estimate yet", false],
      ["CAN frames", fmt(r.can, 0) + " /s (inputs " + fmt(r.inputs, 0) + " /s)", true],
      ["GNSS fixes", fmt(r.gps, 1) + " /s", true], ["estimates", fmt(r.est, 0) + " /s", true],
      ["sent", fmt(r.tx, 0) + " frames/s from " + (h.address || "-"), true],
      ["dropped frames", h.dropped_frames, !h.dropped_frames], ["bad / unknown frames", h.bad_frames + " / " + h.unknown_pgn_frames, true],
      ["late frames, skipped steps", h.late_frames + ", " + h.skipped_steps, !h.skipped_steps],
      ["map", h.map, !/^(ERROR|NOT MAPPING|no GNSS)/.test(String(h.map || ""))],
      ["viewers", s.viewers, true],
    ];
    if (h.behind) rows.push(["schedule", h.behind, false]);
    const tb = $("health"); tb.textContent = "";
    for (const [k, v, ok] of rows) {
      const tr = tb.insertRow(); tr.insertCell().textContent = k;
      const td = tr.insertCell(); td.textContent = (v === undefined || v === null) ? "-" : v; if (!ok) td.className = "bad";
    }
  }

  $("map-field").addEventListener("change", drawMap);
  connect();
})();
