// cnctwin dashboard: small vanilla JS over the JSON API (no build step, no network access).
"use strict";
const cnctwin = (() => {
  const cfg = () => JSON.parse(document.getElementById("cfg").textContent || "{}");
  const $ = (id) => document.getElementById(id);
  const esc = (v) => String(v ?? "–").replace(/[&<>"]/g, (c) => ({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;"}[c]));
  // numbers as an engineer reads them: integers whole, no exponent between 1e-3 and 1e9
  // (100 810.5 s, not 1.0081e+5), five significant digits, trailing zeros dropped
  const fmt = (v) => {
    if (typeof v !== "number") return esc(v);
    if (Number.isInteger(v)) return String(v);
    if (!Number.isFinite(v)) return String(v);
    const a = Math.abs(v);
    if (a !== 0 && (a < 1e-3 || a >= 1e9)) return v.toPrecision(4);
    const digits = Math.max(0, Math.min(6, 4 - Math.floor(Math.log10(a || 1))));
    return String(Number(v.toFixed(digits)));
  };

  async function getJSON(url) {
    const r = await fetch(url);
    const body = await r.json().catch(() => ({}));
    if (!r.ok) throw new Error(body.detail || `${r.status} ${r.statusText}`);
    return body;
  }

  // a time span as an operator reads it: 42 s, 12 min, 3 h 05 min
  const duration = (s) => {
    if (typeof s !== "number" || !Number.isFinite(s)) return "–";
    if (s < 90) return `${Math.round(s)} s`;
    if (s < 5400) return `${Math.round(s / 60)} min`;
    const h = Math.floor(s / 3600), m = Math.round((s - 3600 * h) / 60);
    return `${h} h ${String(m).padStart(2, "0")} min`;
  };
  const TOOL_COLS = ["tool", "name", "used", "planned", "wear [µm]", "wear limit [µm]", "holes left",
    "time left", "basis"];

  function table(el, columns, rows, max) {
    const shown = max ? rows.slice(0, max) : rows;
    el.innerHTML = `<thead><tr>${columns.map((c) => `<th>${esc(c)}</th>`).join("")}</tr></thead><tbody>` +
      shown.map((r) => `<tr>${columns.map((c) => `<td>${fmt(r[c])}</td>`).join("")}</tr>`).join("") + "</tbody>";
  }

  // ---------------------------------------------------------------- signal plot
  // hole numbers are whole: no 0.5 or 1.5 ticks on a short run
  const holeAxis = (holes) => ({title: {text: "hole"}, tickformat: "d",
    ...((holes || []).length <= 20 ? {dtick: 1} : {})});

  function stackedLayout(traces, title) {
    const n = traces.length, gap = 0.04, h = (1 - gap * (n - 1)) / n;
    const layout = {margin: {l: 70, r: 20, t: 30, b: 40}, showlegend: false, title: {text: title, font: {size: 13}},
      xaxis: {title: {text: "time since first cycle [s]"}, anchor: n > 1 ? `y${n}` : "y"}, hovermode: "x"};
    traces.forEach((t, i) => {
      const key = i === 0 ? "yaxis" : `yaxis${i + 1}`;
      const lo = 1 - (i + 1) * h - i * gap;
      layout[key] = {domain: [Math.max(0, lo), lo + h], title: {text: t.axisTitle, font: {size: 11}}};
    });
    return layout;
  }

  function recordingPage(c) {
    const plot = $("plot"), info = $("plot-info"), sel = $("signals");
    for (const o of sel.options) o.selected = c.signals.includes(o.value);
    let range = null, busy = 0;
    const given = new URLSearchParams(location.search);  // a shared link: ?start_s=..&end_s=..
    if (given.has("start_s") && given.has("end_s")) {
      const a = parseFloat(given.get("start_s")), b = parseFloat(given.get("end_s"));
      if (Number.isFinite(a) && Number.isFinite(b) && b > a) range = [a, b];
    }
    async function draw() {
      const names = Array.from(sel.selectedOptions).map((o) => o.value);
      if (!names.length) { info.textContent = "pick one or more signals"; return; }
      const px = Math.max(200, Math.min(4000, Math.round(plot.clientWidth || 1000)));
      const q = new URLSearchParams({px: String(px)});
      if (range) { q.set("start_s", String(range[0])); q.set("end_s", String(range[1])); }
      const mine = ++busy;
      info.textContent = "loading…";
      try {
        const res = await Promise.all(names.map((n) => getJSON(`${c.api}/signals/${encodeURIComponent(n)}?${q}`)));
        if (mine !== busy) return;
        const traces = res.map((r, i) => ({x: r.x, y: r.y, type: "scatter", mode: "lines", name: r.signal,
          line: {width: 1}, yaxis: i === 0 ? "y" : `y${i + 1}`, axisTitle: `${r.signal} [${r.unit}]`}));
        const layout = stackedLayout(traces, "");
        if (range) layout.xaxis.range = range;
        await Plotly.react(plot, traces, layout, {responsive: true, displaylogo: false});
        plot.dataset.points = String(res.reduce((a, r) => a + r.n_points, 0));
        info.textContent = res.map((r) => `${r.signal}: ${r.n_points} of ${r.n_source} samples` +
          (r.exact ? " (full resolution)" : ` (min/max of ${r.px} px)`) + (r.n_gaps ? `, ${r.n_gaps} gaps` : "") +
          (r.note ? ` – ${r.note}` : "")).join("; ");
      } catch (err) { info.textContent = `error: ${err.message}`; }
    }
    const showRange = () => {  // the picker shows what is drawn (zoom included)
      for (const [id, v] of [["range-start", range && range[0]], ["range-end", range && range[1]]]) {
        const text = range ? Number(v).toFixed(3) : "";
        $(id).value = text;
        $(id).setAttribute("value", text);  // also in the page's markup (saved pages, tests)
      }
    };
    const hook = () => plot.on && plot.on("plotly_relayout", (ev) => {
      if (ev["xaxis.range[0]"] !== undefined) { range = [ev["xaxis.range[0]"], ev["xaxis.range[1]"]]; showRange(); draw(); }
      else if (ev["xaxis.autorange"]) { range = null; showRange(); draw(); }
    });
    $("plot-btn").onclick = () => draw();
    $("reset-btn").onclick = () => { range = null; showRange(); draw(); };
    $("range-btn").onclick = () => {
      const a = parseFloat($("range-start").value), b = parseFloat($("range-end").value);
      const lo = Number.isFinite(a) ? a : 0, hi = Number.isFinite(b) ? b : c.duration_s;
      if (!(hi > lo)) { info.textContent = "the end of the range must come after its start"; return; }
      range = [lo, hi];
      draw();
    };
    showRange();
    draw().then(hook);
    useCases(c.api);
  }

  // ---------------------------------------------------------------- holes, trends, anomalies
  const HOLE_COLS = ["hole", "set", "position_in_set", "start_s", "depth_mm", "speed_rpm", "current_mean_a",
    "torque_first_nm", "torque_mean_nm", "energy_j", "thrust_proxy", "dev_x_maxabs_mm", "dev_y_maxabs_mm",
    "dev_z_rms_mm", "tool", "cycle"];

  async function useCases(api) {
    const info = $("holes-info");
    try {
      const h = await getJSON(`${api}/holes`);
      info.textContent = `${h.n_holes} holes; spindle model: ${h.spindle_model || "–"}; thrust: ${h.thrust_source || "–"}` +
        (h.issues.length ? `; notes: ${h.issues.join(" | ")}` : "");
      if (!h.n_holes) {  // nothing drawn empty: no table header without rows, no blank plots
        for (const id of ["holes-table", "trend-plot", "temperature-plot"]) $(id).style.display = "none";
        return;
      }
      table($("holes-table"), HOLE_COLS.filter((c) => h.columns.includes(c)), h.rows, 500);
      const t = await getJSON(`${api}/trends`);
      $("trend-notes").innerHTML = t.notes.map((n) => `<li>${esc(n)}</li>`).join("");
      const traces = [
        {x: t.hole, y: t.torque_mean_nm, mode: "markers", name: "torque per hole [Nm]", marker: {size: 4}},
      ];
      if (t.torque_ma_nm) traces.push({x: t.hole, y: t.torque_ma_nm, mode: "lines", name: `${t.window}-hole moving average [Nm]`});
      if (t.relative_increase) traces.push({x: t.hole, y: t.relative_increase.map((v) => v === null ? null : 100 * v),
        mode: "lines", name: `increase over the first ${t.baseline_holes} holes [%]`, yaxis: "y2"});
      await Plotly.react($("trend-plot"), traces, {margin: {l: 60, r: 60, t: 30, b: 40}, title: {text: "cutting torque per hole (wear indicator)", font: {size: 13}},
        xaxis: holeAxis(t.hole), yaxis: {title: {text: "torque [Nm]"}},
        // its own round ticks (plotly's default for an overlaying axis follows the left one's
        // grid: 1.184/0.671/0.159 %), no second grid
        yaxis2: {title: {text: "increase [%]"}, overlaying: "y", side: "right", tickmode: "auto",
          nticks: 6, showgrid: false, zeroline: false}, legend: {orientation: "h"}},
        {responsive: true, displaylogo: false});
      if (t.temperature) {
        const T = t.temperature;
        await Plotly.react($("temperature-plot"), [
          {x: T.hole, y: T.camera_c, mode: "markers", name: "thermal camera [°C]"},
          {x: T.hole, y: T.predicted_c, mode: "lines", name: `soft sensor [°C] (rmse ${fmt(T.rmse_c)} °C)`}],
          {margin: {l: 60, r: 20, t: 30, b: 40}, title: {text: "tool temperature", font: {size: 13}},
            xaxis: holeAxis(T.hole), yaxis: {title: {text: "°C"}}, legend: {orientation: "h"}},
          {responsive: true, displaylogo: false});
      } else { $("temperature-plot").style.display = "none"; }
      if (t.quality && t.quality.length) table($("quality-table"), Object.keys(t.quality[0]), t.quality, 500);
    } catch (err) { info.textContent = `error: ${err.message}`; }
    const run = $("anomaly-run");
    run.onclick = async () => {
      const ai = $("anomaly-info");
      ai.textContent = "running…";
      try {
        const a = await getJSON(`${api}/anomalies?detector=${encodeURIComponent($("detector").value)}`);
        ai.textContent = `${a.detector}: ${a.alarms_s.length} alarms in ${fmt(a.monitored_s)} s scored` +
          (a.alarms_s.length ? ` at ${a.alarms_s.map((s, i) => `${fmt(s)} s (hole ${a.alarm_holes[i]})`).join(", ")}` : "");
        const shapes = a.alarms_s.map((s) => ({type: "line", x0: s, x1: s, yref: "paper", y0: 0, y1: 1, line: {color: "red", width: 1}}));
        await Plotly.react($("anomaly-plot"), [{x: a.score_x, y: a.score_y, type: "scatter", mode: "lines", line: {width: 1}, name: "score"}],
          {margin: {l: 60, r: 20, t: 30, b: 40}, shapes, xaxis: {title: {text: "time [s]"}}, yaxis: {title: {text: "score"}},
            title: {text: "detector score (red: alarms)", font: {size: 13}}}, {responsive: true, displaylogo: false});
      } catch (err) { ai.textContent = `error: ${err.message}`; }
    };
  }

  // ---------------------------------------------------------------- live
  function livePage(c) {
    const plot = $("live-plot"), state = $("live-state"), holes = [], tools = new Map(), events = $("live-events");
    const xs = [], ys = [];
    let WINDOW_S = Number($("live-window").value) || 30;
    let t0 = null, cycleTime = 0.002, pending = false;
    Plotly.newPlot(plot, [{x: [], y: [], type: "scatter", mode: "lines", line: {width: 1}, name: "cutting torque"}],
      {margin: {l: 60, r: 20, t: 30, b: 40}, title: {text: "cutting torque [Nm] (last 30 s)", font: {size: 13}},
        xaxis: {title: {text: "time [s]"}}, yaxis: {title: {text: "Nm"}}}, {responsive: true, displaylogo: false});
    const redraw = () => {
      pending = false;
      // new arrays: Plotly.react compares data by reference and would skip a mutated one
      Plotly.react(plot, [{x: xs.slice(), y: ys.slice(), type: "scatter", mode: "lines", line: {width: 1}}], plot.layout);
      plot.dataset.points = String(xs.length);
    };
    $("live-window").onchange = (ev) => {
      WINDOW_S = Number(ev.target.value) || 30;
      const label = ev.target.selectedOptions[0].textContent;
      Plotly.relayout(plot, {"title.text": `cutting torque [Nm] (${label})`});
    };
    // a finished run's stream ends after its final status (the page shows the final counts
    // and stops loading); a running one is followed
    const q = new URLSearchParams({from_start: "true", until_finished: "true"});
    const limit = new URLSearchParams(location.search).get("limit");
    if (limit) q.set("limit", limit);
    if (c.machine) q.set("machine", c.machine);
    const es = new EventSource(`/api/live/stream?${q}`);
    es.addEventListener("end", (ev) => {
      es.close();
      redraw();  // the last data now, not on a next animation frame that may never come
      const m = JSON.parse(ev.data);
      state.textContent = m.finished ? `run finished: ${m.events} results (reload to follow a new run)`
        : "stream ended (limit reached)";
      state.dataset.finished = m.finished ? "true" : "false";
    });
    es.onopen = () => { state.textContent = "connected"; };
    es.onerror = () => { state.textContent = "disconnected – retrying"; };
    es.addEventListener("torque", (ev) => {
      const m = JSON.parse(ev.data);
      if (t0 === null) t0 = m.first_cycle;
      for (let i = 0; i < m.n; i++) { xs.push((m.first_cycle + i - t0) * cycleTime); ys.push(m.torque_nm[i]); }
      const cut = xs.length ? xs[xs.length - 1] - WINDOW_S : 0;
      let k = 0; while (k < xs.length && xs[k] < cut) k++;
      if (k) { xs.splice(0, k); ys.splice(0, k); }
      if (!pending) { pending = true; requestAnimationFrame(redraw); }
    });
    es.addEventListener("run", (ev) => {
      // a new run of the runtime into the same directory: start a new view, so the plot
      // never mixes two runs (time running backwards)
      const m = JSON.parse(ev.data);
      if (t0 !== null || holes.length) {
        xs.length = 0; ys.length = 0; t0 = null; holes.length = 0; tools.clear();
        table($("live-holes"), [], [], 200);
        table($("live-tools"), [], [], 50);
        redraw();
      }
      const li = document.createElement("li");
      li.className = "run";
      li.textContent = `run started ${m.started || ""} (${m.source || ""})`;
      events.prepend(li);
      plot.dataset.run = m.started || "";
    });
    es.addEventListener("hole", (ev) => {
      const m = JSON.parse(ev.data);
      holes.push(m.row);
      table($("live-holes"), HOLE_COLS.filter((c) => c in m.row), holes.slice().reverse(), 200);
    });
    // each tool's life after its last hole (docs/tool-life.md): used, wear, remaining
    es.addEventListener("tool_life", (ev) => {
      const m = JSON.parse(ev.data);
      const left = m.remaining_holes === null || m.remaining_holes === undefined
        ? (m.never_reaches_limit ? "beyond the trend" : (m.reason || "unknown"))
        : `${fmt(m.remaining_holes)} (90 %: ${fmt(m.remaining_low)} – ${m.remaining_high === null ? "∞" : fmt(m.remaining_high)})`;
      tools.set(m.tool, {tool: `T${m.tool}`, name: m.name, used: m.used_holes, planned: m.life_holes,
        "wear [µm]": m.wear_um, "wear limit [µm]": m.wear_limit_um, "holes left": left,
        "time left": m.remaining_s === null || m.remaining_s === undefined ? "–" : duration(m.remaining_s),
        basis: m.basis});
      table($("live-tools"), TOOL_COLS, [...tools.values()], 50);
    });
    for (const kind of ["alarm", "gap"]) es.addEventListener(kind, (ev) => {
      const m = JSON.parse(ev.data);
      const li = document.createElement("li");
      li.className = kind;
      li.textContent = kind === "alarm" ? `alarm ${m.detector}: score ${fmt(m.score)} at cycle ${m.cycle} (${m.time || ""})`
        : `gap: ${m.missing_cycles} cycles (${fmt(m.missing_s)} s) after ${m.after_cycle}`;
      events.prepend(li);
    });
    es.addEventListener("status", (ev) => {
      const s = JSON.parse(ev.data);
      $("live-status").innerHTML = ["state", "cycles", "cycles_per_s_recent", "lag_s", "holes", "alarms", "gaps", "missing_cycles", "late_rows"]
        .filter((k) => k in s).map((k) => `<dt>${esc(k)}</dt><dd>${fmt(s[k])}</dd>`).join("");
      state.textContent = `connected – last status seq ${s.seq ?? ""}`;
    });
  }

  // ---------------------------------------------------------------- twin comparison
  async function comparePage(c) {
    const doc = await getJSON(c.api);
    for (const el of document.querySelectorAll(".compare-plot")) {
      const p = doc.plots[el.dataset.axis];
      if (!p) continue;
      const tr = [
        {x: p.fe_meas_um.x, y: p.fe_meas_um.y, name: "machine", yaxis: "y", axisTitle: "following error [µm]"},
        {x: p.fe_pred_um.x, y: p.fe_pred_um.y, name: "twin", yaxis: "y", line: {dash: "dash"}},
        {x: p.fe_diff_um.x, y: p.fe_diff_um.y, name: "machine - twin", yaxis: "y2", axisTitle: "machine - twin [µm]"},
      ];
      if (p.i_meas_a) {
        tr.push({x: p.i_meas_a.x, y: p.i_meas_a.y, name: "current, machine", yaxis: "y3", axisTitle: "current [A]"});
        tr.push({x: p.i_pred_a.x, y: p.i_pred_a.y, name: "current, twin", yaxis: "y3", line: {dash: "dash"}});
      }
      const panels = tr.filter((t) => t.axisTitle);
      const layout = stackedLayout(panels, "");
      layout.xaxis.title.text = "time [s]";
      layout.showlegend = true;
      layout.legend = {orientation: "h"};
      layout.shapes = p.spans_s.map(([a, b]) => ({type: "rect", xref: "x", yref: "paper", x0: a, x1: b, y0: 0, y1: 1,
        fillcolor: "rgba(211,47,47,0.15)", line: {width: 0}}));
      const traces = tr.map((t) => ({type: "scatter", mode: "lines", line: {width: 1, ...(t.line || {})}, ...t}));
      await Plotly.react(el, traces, layout, {responsive: true, displaylogo: false});
      el.dataset.points = String(traces.reduce((n, t) => n + t.x.length, 0));
    }
  }

  function start() {
    const page = document.body.dataset.page, c = cfg();
    if (page === "recording") recordingPage(c);
    else if (page === "machine") useCases(c.api);
    else if (page === "live") livePage(c);
    else if (page === "compare") comparePage(c);
    if ($("plant")) setInterval(refreshPlant, 2000);
    // the page's own width, for the layout check of the tests (nothing wider than the window)
    document.body.dataset.scrollWidth = String(document.documentElement.scrollWidth);
  }

  // ---------------------------------------------------------------- plant tiles
  async function refreshPlant() {
    try {
      const r = await fetch("/plant/tiles");
      if (r.ok) $("plant").innerHTML = await r.text();
    } catch (err) { /* the next refresh tries again; the tiles say how old their data is */ }
  }
  return {start, getJSON};
})();
