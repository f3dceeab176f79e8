"""Server-rendered HTML pages of the dashboard (no template engine, no build step).

Each page is a small HTML document that loads ``/static/style.css``, ``/static/app.js`` and
the locally served ``/static/plotly.min.js``; the tables that describe recordings are rendered
here, the plots and the use-case tables are filled by ``app.js`` from the JSON API.
"""

from __future__ import annotations

import html
import json
import math
import urllib.parse
from collections.abc import Sequence
from typing import Any

from cnctwin.signals import parse_column
from cnctwin.web.sources import Entry

__all__ = ["fleet_page", "live_page", "machine_page", "overview_page", "plant_page",
           "plant_tiles", "recording_page"]


def _e(v: object) -> str:
    return html.escape("" if v is None else str(v))


def _q(v: str) -> str:
    return urllib.parse.quote(v, safe="")


def _num(v: float | None, fmt: str = "{:.4g}", unit: str = "") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return fmt.format(v) + (f" {unit}" if unit else "")


def _time(v: Any) -> str:
    if v is None:
        return "–"
    text = v.isoformat() if hasattr(v, "isoformat") else str(v)
    return _e(text.replace("+00:00", "Z"))


def _short_time(v: Any, *, same_day_as: Any = None) -> str:
    """``2023-12-22 13:23:41`` (to the second; the full time in the tooltip), only the time of
    day when ``same_day_as`` is on the same day."""
    if v is None:
        return "–"
    full = _time(v)
    text = full.replace("T", " ")
    if len(text) >= 19:
        day, clock = text[:10], text[11:19]
        ref = _time(same_day_as)[:10] if same_day_as is not None else None
        text = clock if ref == day else f"{day} {clock}"
    return f'<span title="{full}">{_e(text)}</span>'


def _page(title: str, body: str, *, page: str, config: dict[str, Any] | None = None,
          plotly: bool = True) -> str:
    cfg = json.dumps(config or {}).replace("</", "<\\/")
    scripts = '<script src="/static/plotly.min.js"></script>\n' if plotly else ""
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{_e(title)}</title>
<link rel="stylesheet" href="/static/style.css">
{scripts}<script src="/static/app.js"></script>
</head><body data-page="{_e(page)}">
<header><a class="brand" href="/">cnctwin</a>
<nav><a href="/">fleet</a> <a href="/plant">plant</a> <a href="/fleet">fleet results</a>
<a href="/live">live</a>
<a href="/api/docs">API</a></nav></header>
<main>
{body}
</main>
<script type="application/json" id="cfg">{cfg}</script>
<script>document.addEventListener("DOMContentLoaded", () => cnctwin.start());</script>
</body></html>
"""


def _gaps(n: int, missing_s: float) -> str:
    return f"{n} ({missing_s:.3g} s)" if n else "0"


def _step(step_s: float) -> str:
    # wall clock vs counter across gaps; shown only when it is more than a cycle's worth
    if not math.isfinite(step_s) or step_s < 0.002:
        return ""
    return f' <span class="warn">(clock steps {step_s:.3g} s at gaps)</span>'


def _quality_cells(e: Entry) -> str:
    q = e.quality
    if q is None:
        return "<td colspan=6>–</td>"
    gaps = _gaps(q.n_gaps, q.missing_s)
    flag = ' class="warn"' if q.coverage < 1 or q.partial else ""
    return (f"<td>{_num(q.nominal_rate_hz, '{:g}', 'Hz')}</td>"
            f"<td{flag}>{_num(q.effective_rate_hz, '{:.4g}', 'Hz')}</td>"
            f"<td{flag}>{gaps}</td>"
            f"<td>{_num(q.anchor_jitter_ms, '{:.3g}', 'ms')}{_step(q.clock_step_s)}</td>"
            f"<td{' class=warn' if q.partial else ''}>{'partial' if q.partial else 'no'}</td>"
            f"<td title=\"{_e(chr(10).join(e.issues))}\">{q.n_issues}</td>")


def _clock(v: Any) -> str:
    """UTC time of day of an ISO time (``08:00:03Z``), '–' without one."""
    if not v:
        return "–"
    text = str(v)
    return _e(text[11:19] + "Z") if len(text) >= 19 and text[10] == "T" else _e(text)


def _tile(m: dict[str, Any]) -> str:
    label = str(m.get("label") or m.get("machine") or "?")
    tq, hole, alarm = m.get("torque"), m.get("hole"), m.get("alarm")
    torque = (f"{_num(tq.get('torque_mean_nm'), '{:.2f}', 'Nm')} mean, "
              f"{_num(tq.get('torque_max_nm'), '{:.2f}', 'Nm')} peak at "
              f"{_num(tq.get('speed_rpm'), '{:.0f}', 'rpm')} ({_clock(tq.get('time'))})"
              if tq else "none yet")
    hole_txt = (f"#{_e(hole.get('hole'))}: {_num(hole.get('depth_mm'), '{:.2f}', 'mm')}, "
                f"{_num(hole.get('torque_mean_nm'), '{:.2f}', 'Nm')} "
                f"({_clock(hole.get('time'))}){' partial' if hole.get('partial') else ''}"
                if hole else "none yet")
    alarm_txt = (f"{_e(alarm.get('detector'))}, score {_num(alarm.get('score'), '{:.3g}')} "
                 f"({_clock(alarm.get('time'))})" if alarm else "none")
    age = m.get("status_age_s")
    data_age = m.get("data_age_s")
    seen = (f"status {_num(age, '{:.0f}', 's')} ago, data {_num(data_age, '{:.1f}', 's')} old"
            if age is not None else "no status yet")
    state = str(m.get("state", "waiting"))
    name = m.get("machine") if m.get("machine") != label else ""
    return f"""<div class="tile state-{_e(state)}" data-machine="{_e(label)}">
<div class="tile-head"><a href="/live?machine={_q(label)}">{_e(label)}</a>
<span class="badge">{_e(state)}</span></div>
<div class="muted">{_e(name)} {_e(m.get('reason'))}</div>
<dl class="summary"><dt>torque</dt><dd>{torque}</dd><dt>last hole</dt><dd>{hole_txt}</dd>
<dt>last alarm</dt><dd>{alarm_txt}</dd><dt>counts</dt><dd>{_e(m.get('holes') or 0)} holes,
{_e(m.get('alarms') or 0)} alarms</dd><dt>seen</dt><dd>{seen}</dd></dl></div>"""


def _plural(n: int, word: str) -> str:
    """``1 machine``, ``2 machines``."""
    return f"{n} {word}{'' if n == 1 else 's'}"


def plant_tiles(rows: Sequence[dict[str, Any]]) -> str:
    """One status tile per machine (:func:`cnctwin.web.plant.plant_state` rows).

    Parameters
    ----------
    rows : sequence
        One :func:`cnctwin.web.plant.machine_state` per machine.

    Returns
    -------
    str
        HTML of the tiles.
    """
    if not rows:
        return ('<p class="muted">No edge runtimes: start the dashboard with '
                "<code>--live DIR</code> (repeatable) or <code>--plant plant.toml</code>.</p>")
    return "".join(_tile(m) for m in rows)


def plant_page(title: str, rows: Sequence[dict[str, Any]]) -> str:
    """The plant at a glance: a tile per machine, refreshed every 2 s.

    Parameters
    ----------
    title : str
        Page title (the dashboard's name).
    rows : sequence
        One :func:`cnctwin.web.plant.machine_state` per machine.

    Returns
    -------
    str
        HTML.
    """
    counts = {st: sum(1 for m in rows if m.get("state") == st) for st in
              ("running", "cutting", "alarm", "stale", "finished", "waiting", "error")}
    summary = ", ".join(f"{n} {st}" for st, n in counts.items() if n) or "no machines"
    body = f"""
<h1>{_e(title)}: plant</h1>
<p class="muted" id="plant-summary">{_plural(len(rows), "machine")}: {_e(summary)}. States:
running (data flows, no cut), cutting, alarm (an anomaly alarm in the last minute of machine
time), stale (no status or no data for 10 s), finished, waiting (not started), error (the
state directory cannot be read: the tile says why).</p>
<div id="plant" class="tiles">{plant_tiles(rows)}</div>
"""
    return _page(f"{title}: plant", body, page="plant", plotly=False)


def _calibration(m: dict[str, Any]) -> str:
    """The machine's calibration cell: its machine file, or a plain 'uncalibrated'."""
    if m.get("machine_file"):
        name = str(m["machine_file"]).replace("\\", "/").rsplit("/", 1)[-1]
        return f'<span title="{_e(m["machine_file"])}">{_e(name)}</span>'
    if m.get("calibrated"):
        return "spindle model given"
    return ('<span class="warn" title="no machine file names this machine: torques use the '
            'library default (thesis parameters)">uncalibrated</span>')


def overview_page(title: str, machines: Sequence[dict[str, Any]], entries: Sequence[Entry], *,
                  live: bool, store_url: str | None,
                  plant: Sequence[dict[str, Any]] = ()) -> str:
    """Fleet and recordings with duration, rate, gaps, jitter, partial flags, last activity;
    the plant's tiles first when edge runtimes are followed.

    Parameters
    ----------
    title : str
        Page title (the dashboard's name).
    machines : sequence
        Fleet rows.
    entries : sequence
        Recordings.
    live : bool
        A live source is followed.
    store_url : str, optional
        The store shown.
    plant : sequence, default ()
        Plant tiles (:func:`cnctwin.web.plant.plant_state`).

    Returns
    -------
    str
        HTML.
    """
    m_rows = "".join(
        f"<tr><td><a href=\"/machines/{_q(m['machine'])}\">{_e(m['machine'])}</a></td>"
        f"<td>{m['n_recordings']}</td><td>{_num(m['duration_s'], '{:.1f}', 's')}</td>"
        f"<td>{m['n_cycles']}</td><td>{_gaps(m['n_gaps'], m['missing_s'])}</td>"
        f"<td>{m['partial']}</td><td>{_time(m['last_activity'])}</td>"
        f"<td>{_calibration(m)}</td></tr>"
        for m in machines)
    r_rows = []
    for e in entries:
        if e.error:
            r_rows.append(f"<tr class=\"error\"><td>{_e(e.label)}</td><td colspan=12>"
                          f"cannot be read: {_e(e.error)}</td></tr>")
            continue
        r_rows.append(
            f"<tr><td class=\"label\"><a href=\"/recordings/{_q(e.id)}\" title=\"{_e(e.id)}\">"
            f"{_e(e.label)}</a></td><td>{_e(e.machine or '?')}</td>"
            f"<td>{_e(e.source_format)}</td><td>{_short_time(e.start_time)}</td>"
            f"<td>{_short_time(e.end_time, same_day_as=e.start_time)}</td>"
            f"<td>{_num(e.duration_s, '{:.3f}', 's')}</td><td>{e.n_cycles}</td>"
            f"{_quality_cells(e)}</tr>")
    src = f"store {_e(store_url)}" if store_url else "recording files"
    tiles = (f'<h2>Plant now</h2><div id="plant" class="tiles">{plant_tiles(plant)}</div>'
             if plant else "")
    machines_html = f"""<h2>Machines</h2>
<table id="machines"><thead><tr><th>machine</th><th>recordings</th><th>duration</th>
<th>cycles</th><th>gaps (missing)</th><th>partial</th><th>last activity (UTC)</th>
<th>calibration</th></tr></thead>
<tbody>{m_rows}</tbody></table>""" if machines else ""
    recordings_html = f"""<h2>Recordings</h2>
<p class="muted">Rate: nominal = 1 / cycle time; effective = recorded cycles per second of the
counter span (gaps lower it). Jitter: scatter of the source's wall-clock stamps about the cycle
counter. Issues: what the reader repaired (hover for the list).</p>
<div class="wide"><table id="recordings"><thead><tr><th>recording</th><th>machine</th>
<th>format</th><th>start (UTC)</th><th>end (UTC)</th><th>duration</th><th>cycles</th><th>rate</th>
<th>effective</th><th>gaps (missing)</th><th>jitter</th><th>partial</th><th>issues</th></tr>
</thead><tbody>{''.join(r_rows)}</tbody></table></div>""" if entries else ""
    body = f"""
<h1>{_e(title)}: fleet</h1>
<p class="muted">Source: {src}. {len(entries)} recordings.
{'<a href="/live">Live view</a> of the edge runtime.' if live else ''}</p>
{tiles}
{machines_html}
{recordings_html}
"""
    return _page(f"{title}: fleet", body, page="overview", plotly=False)


def _signal_picker(signals: Sequence[str], units: dict[str, str]) -> str:
    groups: dict[str, list[str]] = {}
    for s in signals:
        axis = parse_column(s)[1] if "|" in s else "twin (derived)"
        groups.setdefault(axis or "-", []).append(s)
    opts = []
    for axis, names in groups.items():
        items = "".join(f"<option value=\"{_e(n)}\">{_e(n)}"
                        f"{' [' + _e(units[n]) + ']' if units.get(n) else ''}</option>"
                        for n in names)
        opts.append(f"<optgroup label=\"{_e(axis)}\">{items}</optgroup>")
    return (f"<select id=\"signals\" multiple size=\"10\">{''.join(opts)}</select>")


def _default_signals(signals: Sequence[str]) -> list[str]:
    pref = ["CURRENT|SP1", "ENC_POS|Z1", "CMD_SPEED|SP1"]
    chosen = [s for s in pref if s in signals][:2]
    return chosen or list(signals[:1])


def _use_case_sections(calibrated: bool) -> str:
    torque = ("torque columns from the calibrated spindle model" if calibrated else
              "torque columns from the library default (thesis parameters, <b>not calibrated "
              "to this machine</b>; start with --model spindle.json)")
    return f"""
<section id="holes-section"><h2>Holes</h2>
<p class="muted">Per-hole record (cnctwin.usecases.holes.hole_records); {torque}.</p>
<div id="holes-info" class="muted">loading…</div>
<div id="trend-plot" class="plot small"></div>
<div id="temperature-plot" class="plot small"></div>
<div class="scroll"><table id="holes-table"></table></div>
<h3>Hole quality</h3><div class="scroll"><table id="quality-table"></table></div>
<ul id="trend-notes" class="muted"></ul>
</section>
<section id="anomaly-section"><h2>Anomalies</h2>
<p class="muted">Replay through a detector of cnctwin.usecases.anomaly: taught on the first third,
scored on the rest.</p>
<label>detector <select id="detector"><option>physics</option><option>envelope</option>
<option>spectral</option><option>tapping</option></select></label>
<button id="anomaly-run">run</button> <span id="anomaly-info" class="muted"></span>
<div id="anomaly-plot" class="plot small"></div>
</section>"""


def recording_page(title: str, e: Entry, signals: Sequence[str], *, calibrated: bool,
                   twin: bool = False) -> str:
    """Summary, signal-quality figures, signal plot with server-side decimation, use cases.

    Parameters
    ----------
    title : str
        Page title (the dashboard's name).
    e : Entry
        The recording's catalog entry.
    signals : sequence
        Signal names offered.
    calibrated : bool
        A calibrated spindle model is loaded.
    twin : bool, default False
        A machine file is loaded (link to the twin comparison).

    Returns
    -------
    str
        HTML.
    """
    q = e.quality
    qual = "" if q is None else f"""
<dt>rate</dt><dd>{_num(q.nominal_rate_hz, '{:g}', 'Hz')} nominal,
{_num(q.effective_rate_hz, '{:.5g}', 'Hz')} effective
(coverage {_num(q.coverage * 100, '{:.3f}')} %)</dd>
<dt>gaps</dt><dd>{q.n_gaps} ({q.missing_cycles} cycles, {_num(q.missing_s, '{:.4g}', 's')} missing;
longest {_num(q.longest_gap_s, '{:.4g}', 's')}); wraps {q.wraps}</dd>
<dt>clock</dt><dd>{q.n_anchors} wall-clock anchors,
jitter {_num(q.anchor_jitter_ms, '{:.3g}', 'ms')}
(max {_num(q.anchor_max_dev_ms, '{:.3g}', 'ms')}) within gap-free runs;
across gaps the wall clock and the counter differ by {_num(q.clock_step_s, '{:.4g}', 's')}</dd>
<dt>partial</dt><dd>{'<b class="warn">yes</b>' if q.partial else 'no'}</dd>"""
    issues = "".join(f"<li>{_e(i)}</li>" for i in e.issues)
    body = f"""
<h1>{_e(e.label)} <span class="muted">{_e(e.id)}</span></h1>
<dl class="summary"><dt>machine</dt><dd>{_e(e.machine or '?')}</dd>
<dt>format</dt><dd>{_e(e.source_format)}</dd>
<dt>time (UTC)</dt><dd>{_time(e.start_time)} – {_time(e.end_time)}</dd>
<dt>duration</dt><dd>{_num(e.duration_s, '{:.3f}', 's')} ({e.n_cycles} cycles)</dd>{qual}
</dl>
<details><summary>{len(e.issues)} reader notes (meta.issues)</summary><ul>{issues}</ul></details>
{f'<p><a href="/recordings/{_q(e.id)}/compare">compare with the calibrated twin</a></p>'
 if twin else ''}
<section id="signal-section"><h2>Signals</h2>
<div class="row"><div>{_signal_picker(signals, e.units)}
<br><button id="plot-btn">plot</button> <button id="reset-btn">full range</button>
<fieldset id="range-picker"><legend>time range [s from the first cycle]</legend>
<label>from <input id="range-start" type="number" step="any" min="0"
 max="{e.duration_s:.3f}" placeholder="0"></label>
<label>to <input id="range-end" type="number" step="any" min="0"
 max="{e.duration_s:.3f}" placeholder="{e.duration_s:.3f}"></label>
<button id="range-btn">show</button></fieldset></div>
<div class="grow"><div id="plot" class="plot"></div>
<div id="plot-info" class="muted"></div></div></div>
<p class="muted">Min/max envelope of each pixel column computed on the server: no peak is lost;
zoom in (drag) to refetch the range, at full resolution once it fits the plot width.</p>
</section>
{_use_case_sections(calibrated)}
"""
    cfg = {"recording": e.id, "api": f"/api/recordings/{_q(e.id)}",
           "signals": _default_signals(signals), "duration_s": e.duration_s}
    return _page(f"{title}: {e.label}", body, page="recording", config=cfg)


_DEPARTS = '<b class="warn">departs</b>'


def compare_page(title: str, e: Entry, doc: dict[str, Any]) -> str:
    """The recording against the calibrated twin: one row per axis and the spindle."""
    rows = []
    for name, a in doc.get("axes", {}).items():
        cur = a.get("current_residual_ratio")
        rows.append(
            f"<tr><td>{_e(name)}</td><td>{_num(a.get('residual_ratio'), '{:.3f}')}</td>"
            f"<td>{'-' if cur is None else _num(cur, '{:.3f}')}</td>"
            f"<td>{_DEPARTS if a.get('flagged') else 'holds'}</td>"
            f"<td>{_e('; '.join(a.get('reasons', [])) or '-')}</td></tr>")
    sp = doc.get("spindle")
    if sp:
        rows.append(
            f"<tr><td>spindle (air current)</td><td>-</td>"
            f"<td>{_num(sp.get('residual_ratio'), '{:.3f}')}</td>"
            f"<td>{_DEPARTS if sp.get('flagged') else 'holds'}</td>"
            f"<td>{_e('; '.join(sp.get('reasons', [])) or '-')}</td></tr>")
    skipped = "".join(f"<li>{_e(k)}: {_e(v)}</li>" for k, v in doc.get("skipped", {}).items())
    body = f"""
<h1>{_e(e.label)} against its twin</h1>
<p class="muted">Machine file {_e(doc.get('machine_file', ''))}. The twin is driven with the
recording's own setpoints; residual ratio = rms(machine - twin) / rms(machine) over the moving
cycles; an axis departs where that exceeds {_num(doc.get('limits', {}).get('residual_limit'),
'{:g}')} or a friction/gain moved beyond the calibrated uncertainty
({_num(doc.get('limits', {}).get('k_sigma'), '{:g}')} sigma).</p>
<table><thead><tr><th>axis</th><th>following-error residual ratio [-]</th>
<th>current residual ratio [-]</th><th>twin</th><th>why</th></tr></thead>
<tbody>{''.join(rows)}</tbody></table>
{f'<h3>Not compared</h3><ul>{skipped}</ul>' if skipped else ''}
<div id="compare-plots">{"".join(
    f'<h2>Axis {_e(n)}</h2><div class="plot compare-plot" data-axis="{_e(n)}"></div>'
    for n in doc.get("plots", {}))}</div>
<p class="muted">Per axis: the following error of machine and twin, their difference
(departures shaded) and the motor current (thesis Figs. 3.2/3.3 style), min/max of each pixel
column.</p>
<p><a href="/recordings/{_q(e.id)}">back to the recording</a></p>"""
    return _page(f"{title}: {e.label} vs twin", body, page="compare",
                 config={"api": f"/api/recordings/{_q(e.id)}/compare"})


def machine_page(title: str, machine: str, entries: Sequence[Entry], *, calibrated: bool,
                 ) -> str:
    """Hole record and trends over every recording of one machine (time order).

    Parameters
    ----------
    title : str
        Page title (the dashboard's name).
    machine : str
        Machine name.
    entries : sequence
        Its recordings.
    calibrated : bool
        A calibrated spindle model is loaded.

    Returns
    -------
    str
        HTML.
    """
    rows = "".join(f"<li><a href=\"/recordings/{_q(e.id)}\">{_e(e.label)}</a> "
                   f"{_time(e.start_time)}, {_num(e.duration_s, '{:.1f}', 's')}</li>"
                   for e in entries)
    body = f"""
<h1>Machine {_e(machine)}</h1>
<p class="muted">{len(entries)} recordings; the hole record continues across them in time
order.</p><ul>{rows}</ul>
{_use_case_sections(calibrated)}
"""
    cfg = {"machine": machine, "api": f"/api/machines/{_q(machine)}"}
    return _page(f"{title}: {machine}", body, page="machine", config=cfg)


def live_page(title: str, results: str | None, *, machine: str | None = None,
              machines: Sequence[str] = ()) -> str:
    """Edge-runtime status, rolling cutting torque, holes, alarms and each tool's life as they
    arrive (SSE);
    a machine picker when several runtimes are followed.

    Parameters
    ----------
    title : str
        Page title (the dashboard's name).
    results : str, optional
        The followed ``results.jsonl``; None without a live source.
    machine : str, optional
        Label of the machine shown.
    machines : sequence, default ()
        Labels of all followed machines.

    Returns
    -------
    str
        HTML.
    """
    if results is None:
        body = ("<h1>Live</h1><p>No live source. Start the dashboard with "
                "<code>--live DIR</code>, the <code>--out DIR</code> of <code>cnctwin edge "
                "run</code>.</p>")
        return _page(f"{title}: live", body, page="none", plotly=False)
    picker = ""
    if len(machines) > 1:
        opts = "".join(f'<option value="{_e(m)}"{" selected" if m == machine else ""}>{_e(m)}'
                       "</option>" for m in machines)
        picker = (f'<form method="get" action="/live"><label>machine <select name="machine" '
                  f'onchange="this.form.submit()">{opts}</select></label></form>')
    body = f"""
<h1>Live{f": {_e(machine)}" if machine else ""} <span class="muted">{_e(results)}</span></h1>
{picker}
<label>window <select id="live-window"><option value="30" selected>last 30 s</option>
<option value="120">last 2 min</option><option value="600">last 10 min</option>
<option value="3600">last hour</option></select></label>
<div id="live-state" class="muted">connecting…</div>
<dl id="live-status" class="summary"></dl>
<div id="live-plot" class="plot"></div>
<div class="row"><div class="grow"><h2>Holes</h2><div class="scroll">
<table id="live-holes"></table></div></div>
<div><h2>Alarms and gaps</h2><ul id="live-events"></ul></div></div>
<h2>Tools</h2><p class="muted">each tool's life after its last hole (with
<code>edge run --tools</code>; docs/tool-life.md)</p>
<div class="scroll"><table id="live-tools"></table></div>
"""
    return _page(f"{title}: live", body, page="live",
                 config={"results": results, "machine": machine})


_FLEET_SORTS = (("alarms", "alarms"), ("wear", "wear"), ("drift", "drift"),
                ("quality", "data quality"))


def fleet_page(title: str, rows: Sequence[dict[str, Any]], *, source: str | None,
               sort: str, tables: Sequence[str]) -> str:
    """Machines ranked by alarms, wear, drift or data quality (``cnctwin fleet`` results),
    each linking to its machine page.

    Parameters
    ----------
    title : str
        Page title (the dashboard's name).
    rows : sequence
        Ranked machines (:func:`cnctwin.fleet.summary.fleet_summary` rows).
    source : str, optional
        The result folder.
    sort : str
        Ranking key.
    tables : sequence
        Job tables found.

    Returns
    -------
    str
        HTML.
    """
    if source is None:
        body = f"""
<h1>{_e(title)}: fleet results</h1>
<p>No fleet results to show. Run a fleet job and serve its result directory:</p>
<pre>cnctwin fleet health --store STORE --out RES
cnctwin fleet wear --store STORE --out RES
cnctwin fleet quality --store STORE --out RES
cnctwin web --store STORE --fleet RES</pre>"""
        return _page(f"{title}: fleet results", body, page="fleet", plotly=False)
    links = " ".join(
        f"<b>{_e(label)}</b>" if key == sort else f'<a href="/fleet?sort={key}">{_e(label)}</a>'
        for key, label in _FLEET_SORTS)

    def pct(v: Any) -> str:
        return _num(v * 100 if isinstance(v, float) else v, "{:+.1f}", "%")

    trs = []
    for r in rows:
        warn = ' class="warn"' if r["n_alarms"] else ""
        cov = r["coverage_min"]
        cov_cls = ' class="warn"' if isinstance(cov, float) and cov < 1 else ""
        trs.append(
            f"<tr{warn}><td><a href=\"/machines/{_q(r['machine'])}\">{_e(r['machine'])}</a>"
            f"</td><td>{r['days']}</td><td>{r['n_alarms']}</td><td>{_e(r['alarm_kinds'])}</td>"
            f"<td>{_e(r['first_alarm'] or '–')}</td><td>{pct(r['wear_rise'])}</td>"
            f"<td title=\"{_e(r.get('drift_of', ''))}\">{pct(r['max_drift'])}"
            f"{' ' + _e(r['drift_of']) if r.get('drift_of') else ''}</td>"
            f"<td{cov_cls}>{_num(cov, '{:.4f}')}</td>"
            f"<td>{r['missing_cycles']}</td><td>{_num(r['jitter_ms_max'], '{:.3g}', 'ms')}</td>"
            f"<td>{r['partial_partitions']}</td></tr>")
    body = f"""
<h1>{_e(title)}: fleet results</h1>
<p class="muted">From {_e(source)} ({_e(', '.join(tables))}). {len(rows)} machines, worst first.
Rank by: {links}.</p>
<p class="muted">Wear: largest rise of the mean cutting torque per hole over the tool's first
day. Drift: largest change of Kv, axis Coulomb friction or spindle friction current from the
machine's own first day. Alarms: <code>cnctwin fleet health</code> (docs/fleet.md).</p>
<table id="fleet"><thead><tr><th>machine</th><th>days</th><th>alarms</th><th>kinds</th>
<th>first alarm</th><th>wear</th><th>drift</th><th>coverage (min)</th><th>missing cycles</th>
<th>jitter (max)</th><th>partial days</th></tr></thead>
<tbody>{''.join(trs)}</tbody></table>
"""
    return _page(f"{title}: fleet results", body, page="fleet", plotly=False)
