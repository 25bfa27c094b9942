"use strict";
// The live page: reads the server-sent events of /events (JSON of the state, docs/live.md) and
// shows them. Read-only: nothing here sends anything but GET.
(function () {
  const token = new URLSearchParams(location.search).get("token");
  const events = "events" + (token ? "?token=" + encodeURIComponent(token) : "");
  const $ = (id) => document.getElementById(id);
  const fixed = (x, n) => (x === null || x === undefined ? "–" : x.toFixed(n));
  // The report's colours for one circle: ccw dark blue, cw orange (plot.rs PALETTE[0], [1]).
  const COLOUR = { ccw: "#1f77b4", cw: "#ff7f0e" };
  const SVG = "http://www.w3.org/2000/svg"; // a namespace name, never fetched
  const el = (name, attrs) => {
    const e = document.createElementNS(SVG, name);
    for (const k in attrs) e.setAttribute(k, attrs[k]);
    return e;
  };
  // The report's scale: rings in a 1-2-5 step, about 4 out to the largest deviation; the zero
  // ring at 0.6 of the radius, -outer..+outer mapped to 0.2..1.0.
  function scale(maxdev) {
    maxdev = Math.max(maxdev, 1e-3);
    const raw = maxdev / 4;
    const mag = Math.pow(10, Math.floor(Math.log10(raw)));
    const step = [1, 2, 5, 10].map((k) => k * mag).find((s) => s >= raw) || 10 * mag;
    const rings = Math.max(1, Math.ceil(maxdev / step));
    return { step: step, rings: rings, outer: rings * step };
  }
  function drawTrace(trace) {
    const svg = $("polar");
    while (svg.firstChild) svg.removeChild(svg.firstChild);
    const pts = trace ? trace.points : [];
    const maxdev = pts.reduce((m, p) => Math.max(m, Math.abs(p.dev_um)), 0);
    const s = scale(maxdev);
    const rad = (dev) => 0.6 + (0.4 * dev) / s.outer;
    for (let i = -s.rings; i <= s.rings; i++) {
      svg.appendChild(el("circle", { cx: 0, cy: 0, r: rad(i * s.step), fill: "none",
        stroke: i === 0 ? "#00a000" : "#ddd", "stroke-width": i === 0 ? 0.006 : 0.003 }));
    }
    // The inner, zero and outer rings' deviation, between the spokes (105°), as the report's.
    const la = (105 * Math.PI) / 180;
    for (const v of [-s.outer, 0, s.outer]) {
      const t = el("text", { x: (rad(v) * Math.cos(la)).toFixed(4),
        y: (-rad(v) * Math.sin(la)).toFixed(4), "font-size": 0.055, "text-anchor": "middle",
        "dominant-baseline": "middle", fill: "#444", class: "ring_label" });
      t.textContent = v === 0 ? "0 µm" : (v > 0 ? "+" : "") + v + " µm";
      svg.appendChild(t);
    }
    for (const sense of ["ccw", "cw"]) {
      const mine = pts.filter((p) => p.sense === sense);
      const xy = mine.map((p) => {
        const a = (p.angle_deg * Math.PI) / 180, r = rad(p.dev_um);
        return (r * Math.cos(a)).toFixed(4) + "," + (-r * Math.sin(a)).toFixed(4);
      });
      const line = el("polyline", { points: xy.join(" "), fill: "none", stroke: COLOUR[sense],
        "stroke-width": 0.006, "data-sense": sense, "data-points": mine.length });
      line.id = "trace_" + sense;
      svg.appendChild(line);
    }
    svg.setAttribute("data-points", pts.length);
    $("trace_title").textContent = trace
      ? "Circle " + trace.circle + " (R " + trace.radius_mm + " mm): " + pts.length +
        " points, " + s.step + " µm/div"
      : "Trace";
  }
  const h = (name, text, attrs) => {
    const e = document.createElement(name);
    if (text !== undefined && text !== null) e.textContent = text;
    for (const k in attrs || {}) e.setAttribute(k, attrs[k]);
    return e;
  };
  // One circle's diagnosis (CircleDiagnosis in docs/live.md) as a section.
  function circleDiagnosis(f) {
    const sec = h("section", null, { class: "circle", "data-circle": f.circle });
    sec.id = "circle_" + f.circle;
    sec.appendChild(h("h3", "Diagnosis of circle " + f.circle +
      (f.pass === null ? "" : f.pass ? ": PASS" : ": FAIL") + " (" + f.took_ms.toFixed(0) + " ms)"));
    if (f.effects.length > 0) {
      const t = h("table", null, { class: "effects" });
      const head = h("tr");
      for (const c of ["", "effect", "value", "", "of G", "of the mean square", "cause"]) head.appendChild(h("th", c));
      t.appendChild(head);
      for (const e of f.effects) {
        const r = h("tr", null, { "data-effect": e.name });
        r.appendChild(h("td", e.step));
        r.appendChild(h("td", e.name));
        r.appendChild(h("td", e.value, { class: "num" }));
        r.appendChild(h("td", e.unit));
        r.appendChild(h("td", e.g_share_percent === null ? "" : e.g_share_percent + " %", { class: "num" }));
        r.appendChild(h("td", e.share_percent === null ? "" : e.share_percent + " %", { class: "num" }));
        r.appendChild(h("td", e.cause));
        t.appendChild(r);
      }
      sec.appendChild(t);
      const g = f.zones.map((z) => "G " + z.direction + " " + z.g_um + " µm").join(", ");
      sec.appendChild(h("p", g + (f.h_um === null ? "" : ", H " + f.h_um + " µm") +
        " (minimum zone, ISO 230-4)", { class: "zones" }));
    }
    const d = h("details");
    d.appendChild(h("summary", f.effects.length > 0 ? "the full text" : f.text.split("\n")[0]));
    d.appendChild(h("pre", f.text));
    sec.appendChild(d);
    return sec;
  }
  function show(st) {
    $("d_mm").textContent = fixed(st.d_mm, 4);
    $("rate_hz").textContent = fixed(st.rate_hz, 1);
    $("samples").textContent = st.counts.samples;
    $("lost").textContent = st.counts.lost;
    $("dropped").textContent = st.counts.dropped;
    $("corrupt").textContent = st.counts.corrupt;
    $("resets").textContent = st.counts.resets;
    $("elapsed_s").textContent = fixed(st.elapsed_s, 1);
    const p = st.progress;
    if (p) {
      $("plan").hidden = false;
      const where = {
        dwell: "waiting for the feed-in of circle " + p.circle + " of " + p.circles,
        feed_in: "feed-in of circle " + p.circle + " of " + p.circles,
        circle: "circle " + p.circle + " of " + p.circles + (p.sense ? ", " + p.sense : "") +
          (p.on_data_arc ? "" : " (lead-in or overshoot)"),
        feed_out: "feed-out of circle " + p.circle + " of " + p.circles,
        done: "all " + p.circles + " circles run",
      }[p.phase];
      const text = where + ", " + p.percent.toFixed(1) + " %";
      $("progress").textContent = text;
      $("progress").setAttribute("data-phase", p.phase);
      $("percent").value = p.percent;
      drawTrace(st.trace);
    }
    // Each circle's diagnosis while recording: a table of the ranked effects, G per direction
    // and H, the verdict; the full text under "details".
    const list = st.circle_diagnoses || [];
    $("circles_section").hidden = list.length === 0;
    const box = $("circles");
    if (box.childElementCount !== list.length) {
      while (box.firstChild) box.removeChild(box.firstChild);
      for (const f of list) box.appendChild(circleDiagnosis(f));
    }
    if (st.ended) {
      $("ended").hidden = false;
      $("ended").textContent = "Session ended: " + st.ended;
    }
    // Every warning the terminal showed, at the top, as it comes.
    const warnings = st.warnings || [];
    $("warnings").hidden = warnings.length === 0;
    if ($("warnings").childElementCount !== warnings.length) {
      const ul = $("warnings");
      while (ul.firstChild) ul.removeChild(ul.firstChild);
      for (const w of warnings) ul.appendChild(h("li", w));
    }
    if (st.verdict) {
      const v = $("verdict");
      v.hidden = false;
      v.className = "verdict " + (st.verdict.pass ? "pass" : "fail");
      v.textContent = st.verdict.pass ? "PASS" : "FAIL";
      v.appendChild(h("small", st.verdict.text));
    }
    if (st.diagnosis) {
      $("diagnosis").hidden = false;
      $("diagnosis").textContent = st.diagnosis;
    }
    document.body.setAttribute("data-version", st.version);
  }
  if (new URLSearchParams(location.search).get("poll") === "1") {
    // ?poll=1: read /state ten times a second instead of the event stream (for a proxy that
    // holds streams back, and for headless browsers, whose virtual time waits for idle network).
    const state = "state" + (token ? "?token=" + encodeURIComponent(token) : "");
    let shown = -1;
    setInterval(() => {
      fetch(state, { cache: "no-store" })
        .then((r) => r.json())
        .then((st) => {
          $("conn").textContent = "polling";
          if (st.version !== shown) { shown = st.version; show(st); }
        })
        .catch(() => { $("conn").textContent = "no answer"; });
    }, 100);
  } else {
    const source = new EventSource(events);
    source.onopen = () => { $("conn").textContent = "connected"; };
    source.onerror = () => { $("conn").textContent = "reconnecting…"; };
    source.onmessage = (e) => show(JSON.parse(e.data));
  }
})();
