"""The dashboard's HTML, drawn on the server: the dock (``dock_page``, and ``dock_fragment`` that
the live stream sends), one device's history (``device_page``) and its printable handover sheet
(``sheet_page``). Plain HTML and inline SVG; the only script (static/dashboard.js) applies the
live stream and asks for confirmation before an action.
"""

from __future__ import annotations

import html
import json
import os
import time
from typing import Optional
from urllib.parse import quote

from stillpoint.drivers.ax.protocol import display_time, display_times

from .charts import trend_svg
from .records import device_key, local_utc, trends

E = html.escape

# attention first: what needs a person, then what is under way, then what is done
ORDER = {"error": 0, "changed": 0, "detached": 1, "busy": 2, "attached": 2, "identifying": 2,
         "downloading": 3, "verifying": 3, "clearing": 3, "configuring": 3, "verified": 4,
         "seen": 5, "empty": 6, "cleared": 6, "configured": 6}
STATES = ("error", "downloading", "verifying", "verified", "clearing", "cleared", "configuring",
          "configured", "empty")


def _mb(n: Optional[float]) -> str:
    return "-" if n is None else f"{n / 1e6:.1f} MB"


def _dur(s: Optional[float]) -> str:
    if s is None:
        return ""
    s = int(round(s))
    return f"{s // 60} min {s % 60:02d} s" if s >= 60 else f"{s} s"


def _head(title: str, refresh_js: bool = True) -> str:
    return ("<!doctype html><html lang=en><head><meta charset=utf-8>"
            f"<title>{E(title)}</title><meta name=viewport content='width=device-width'>"
            "<link rel=stylesheet href='/static/dashboard.css'>"
            + ("<script src='/static/dashboard.js' defer></script>" if refresh_js else "")
            + "</head><body>")


def _calibration_text(cal: Optional[dict]) -> str:
    if not cal:
        return ""
    t = f"calibration {cal.get('status', '-')}"
    if cal.get("error_before_mg") is not None and cal.get("error_after_mg") is not None:
        t += f" ({cal['error_before_mg']:.1f} → {cal['error_after_mg']:.1f} mg)"
    return t


def _calibration_terms(cal: dict) -> str:
    """Offset (mg) and gain (%) per axis with their standard errors, when estimated."""
    if not cal or cal.get("status") in (None, "identity") or not cal.get("offset"):
        return ""
    unc = cal.get("uncertainty") or {}

    def terms(vals, ses, k, fmt):
        ses = ses or [None] * 3
        return ", ".join(f"{a} {fmt(k(v))}" + (f" ± {fmt(abs(k(se) - k(0)))}" if se is not None else "")
                         for a, v, se in zip("xyz", vals, ses))
    off = terms(cal["offset"], unc.get("offset"), lambda v: 1000.0 * v, lambda v: f"{v:.1f}")
    gain = terms(cal.get("scale") or [1, 1, 1], unc.get("scale"), lambda v: 100.0 * (v - 1.0),
                 lambda v: f"{v:.2f}")
    return f"<br><small>offset mg: {E(off)}<br>gain − 1 %: {E(gain)}</small>"


def sort_rows(rows: list[dict]) -> list[dict]:
    def key(r):
        st = "detached" if r.get("detached") and r["state"] not in ("error",) else r["state"]
        return (ORDER.get(st, 2), r.get("slot") or "", r["device_type"], r["device_id"])
    return sorted(rows, key=key)


def _actions(r: dict, token: Optional[str]) -> str:
    if not token or r.get("running") or r.get("detached"):
        return ""
    key = device_key(r["device_type"], r["device_id"])
    st = r["state"]
    out = []

    def form(action, label, extra="", confirm=None):
        out.append(f"<form method=post action='/action/{action}/{key}' class=act "
                   f"data-confirm='{E(confirm or f'{label} {key}?')}'><input type=hidden name=token value='{E(token)}'>"
                   f"<input type=hidden name=confirm value=''><input type=hidden name=who value=''>{extra}"
                   f"<button name=go value=1 data-action='{action}'>{E(label)}</button></form>")
    form("retry", "Retry")
    if st in ("verified", "cleared", "configured") or (st == "error" and r.get("session")):
        if st == "verified":
            form("verify", "Verify again")
            form("clear", "Clear")
    inputs = ("<input name=subject placeholder='subject id' size=10 autocomplete=off "
              "pattern='[A-Za-z0-9._-]*' title='letters, digits, . _ -'>"
              "<input name=code placeholder='setting code (or the profile)' size=16 "
              "autocomplete=off>")
    if st in ("cleared", "empty"):
        form("configure", "Configure", inputs)
    elif st == "configured" and r.get("next_session") is not None:
        # configured for its session: only again, naming the new session (the sheet is superseded)
        cur, new = r.get("configured_session"), r["next_session"]
        form("configure", "Configure again",
             inputs + f"<input type=hidden name=reconfigure value='{E(str(new))}'>",
             confirm=f"Configure {key} again as session {new}? The handover sheet of session "
                     f"{cur} is superseded.")
    return "".join(out)


def dock_fragment(rows: list[dict], disk: dict, *, token: Optional[str], live: bool) -> str:
    """The part of the dock page the live stream replaces: counts, disk, the table."""
    rows = sort_rows(rows)
    counts: dict[str, int] = {}
    for r in rows:
        counts[r["state"]] = counts.get(r["state"], 0) + 1
    chips = "".join(f"<span class='chip s-{E(s)}'>{E(s)} <b>{n}</b></span>"
                    for s, n in sorted(counts.items(), key=lambda kv: ORDER.get(kv[0], 2)))
    fit = disk.get("downloads_fit")
    out = [f"<p class=summary>{chips or 'no device yet'} <span class=disk>free disk "
           f"{disk['free_bytes'] / 1e9:.1f} GB: about {fit if fit is not None else '-'} more "
           f"download{'s' if fit != 1 else ''}"
           f"{'' if disk.get('from_ledger') else ' of a full 512 MB device'}</span></p>",
           "<table id=dock><thead><tr><th>slot</th><th>device</th><th>type</th><th>state</th>"
           "<th>progress</th><th>MB/s</th><th>battery</th><th>clock</th><th>detail</th>"
           + ("<th>actions</th>" if token else "") + "</tr></thead><tbody>"]
    for r in rows:
        key = device_key(r["device_type"], r["device_id"])
        st = r["state"]
        total, done = r.get("total_bytes") or 0, r.get("done_bytes") or 0
        pct = 100.0 * done / total if total else (100.0 if st in ("verified", "cleared", "configured") else 0.0)
        eta = r.get("eta_s")
        prog = (f"<progress max=100 value='{min(100.0, pct):.0f}'></progress>"
                f"<small>{pct:.0f} %{' · ETA ' + _dur(eta) if eta is not None else ''}</small>"
                if live and (total or st in ("downloading", "verifying")) else "")
        detail = r.get("reason") if st == "error" else (r.get("reason") or r.get("info") or "")
        cal = _calibration_text(r.get("calibration"))
        if cal and st != "error" and cal not in (detail or ""):
            detail = f"{detail}; {cal}" if detail else cal
        if r.get("detached"):
            detail = (detail or "") + " (detached)"
        detail = display_times(detail or "")  # ISO 8601, also in lines recorded by earlier versions
        batt = r.get("battery_pct")
        clk = r.get("clock_offset_s")
        out.append(
            f"<tr class='s-{E(st)}' data-device='{key}' data-state='{E(st)}'>"
            f"<td>{E(r.get('slot') or '-')}</td><td><a href='/device/{key}'>{r['device_id']}</a></td>"
            f"<td>{E(r['device_type'])}</td><td><span class='state s-{E(st)}'>{E(st)}</span></td>"
            f"<td class=progress>{prog}</td><td>{'' if not r.get('mbps') else format(r['mbps'], '.2f')}</td>"
            f"<td>{'-' if batt is None else f'{batt} %'}</td>"
            f"<td>{'-' if clk is None else f'{clk:+.1f} s'}</td><td class=detail>{E(detail or '')}</td>"
            + (f"<td class=actions>{_actions(r, token)}</td>" if token else "") + "</tr>")
    out.append("</tbody></table>")
    return "".join(out)


def dock_page(fragment: str, *, folder: str, live: bool, read_only: bool, message: str = "",
              code: Optional[str] = None) -> str:
    mode = ("live" if live else "from the ledger (no station running)") + \
        (", read-only" if read_only else "")
    return (_head("stillpoint station")
            + f"<header><h1>Station dock</h1><p class=meta>{E(folder)} · {E(mode)}"
            + (" · <span id=live>connecting…</span>" if live else "")
            + (f" · profile setting code <code id=code>{E(code)}</code>" if code else "") + "</p>"
            + ("" if read_only else "<p class=noprint><label>operator <input id=who size=12 "
               "autocomplete=off placeholder='name or initials'></label> (recorded with each "
               "action)</p>") + "</header>"
            + (f"<p class=msg>{E(message)}</p>" if message else "")
            + f"<main id=dockview data-live='{1 if live else 0}'>{fragment}</main></body></html>")


def _files(records, d: dict) -> str:
    links = []
    for label, path in (("raw copy", d.get("cwa_path")), ("MCAP", d.get("mcap_path"))):
        p = records.inside(path)
        if p is not None:
            links.append(f"<a href='/files/{quote(os.path.relpath(p, os.path.realpath(records.folder)))}'>"
                         f"{E(label)}</a>")
    for suffix in (".report.html", ".report.md", ".report.txt", ".html"):
        p = records.inside(os.path.splitext(d.get("cwa_path") or "")[0] + suffix) \
            if d.get("cwa_path") else None
        if p is not None:
            links.append(f"<a href='/files/{quote(os.path.relpath(p, os.path.realpath(records.folder)))}'>report</a>")
            break
    return " · ".join(links) or "-"


def _repairs(d: dict) -> str:
    """What the download's verification re-read and patched ("-": not recorded, a row older
    than the repair columns or a download that did not reach its verification)."""
    from ..download import repairs_text
    if d.get("reread_ranges") is None:
        return "-"
    return repairs_text(d["reread_ranges"], d.get("patched_ranges") or 0) or "none"


def _when(t) -> str:
    loc, utc = local_utc(t)
    return f"{E(loc)}<br><small>{E(utc)}</small>"


def _table(head: list[str], rows: list[list[str]], empty: str) -> str:
    if not rows:
        return f"<p class=none>{E(empty)}</p>"
    return ("<table><thead><tr>" + "".join(f"<th>{E(h)}</th>" for h in head) + "</tr></thead><tbody>"
            + "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
            + "</tbody></table>")


def subject_of(config: dict) -> Optional[str]:
    return ((config.get("settings") or {}).get("metadata") or {}).get("subject")


def device_page(records, hist: dict, *, message: str = "") -> str:
    key = device_key(hist["device_type"], hist["device_id"])
    tr = trends(hist)
    dl_rows = []
    for d in hist["downloads"]:
        cal = d.get("calibration") or {}
        dl_rows.append([
            str(d["session_id"]), f"<span class='state s-{E(d['state'])}'>{E(d['state'])}</span>",
            _when(d.get("started")), _mb(d.get("bytes")),
            E((d.get("sha256") or "-")[:16]), E(str(d.get("bad_sectors") if d.get("bad_sectors") is not None else "-")),
            E(_repairs(d)),
            "-" if d.get("battery_pct") is None else f"{d['battery_pct']} %",
            "-" if d.get("clock_offset_s") is None else f"{d['clock_offset_s']:+.2f} s",
            E(_calibration_text(cal) or "-") + _calibration_terms(cal), E(d.get("reason") or ""),
            _files(records, d)])
    cl_rows = [[_when(c.get("time")), str(c["session_id"]), E(c.get("erase") or "-"),
                f"<span class='state s-{'cleared' if c.get('result') == 'ok' else 'error'}'>"
                f"{E(c.get('result') or '-')}</span>",
                E(c.get("reason") or ""), f"<small>{E(c.get('readback') or '')}</small>"]
               for c in hist["clears"]]
    cf_rows = []
    sup = superseded(hist)
    for c in hist["configurations"]:
        s = c.get("settings") or {}
        what = ", ".join(f"{k} {display_time(s[k]) if k in ('start', 'stop') else s[k]}"
                         for k in ("rate_hz", "range_g", "gyro_dps", "start", "stop") if k in s)
        cf_rows.append([_when(c.get("time")), str(c.get("session_id") if c.get("session_id") is not None else "-"),
                        E(subject_of(c) or "-"), E(what or "-"),
                        "-" if s.get("battery_pct") is None else f"{s['battery_pct']} %",
                        E(c.get("result") or "-")
                        + (f" <a href='/device/{key}/sheet?session={E(str(s.get('session')))}'>"
                           "(superseded)</a>" if c.get("id") in sup else ""),
                        E(display_times(c.get("reason") or ""))])
    ac_rows = [[_when(a.get("time")), E(a.get("action") or ""), E(a.get("who") or ""),
                E(a.get("origin") or ""), E(a.get("result") or ""), E(a.get("reason") or "")]
               for a in hist["actions"]]
    verifications = [a for a in hist["actions"] if a.get("action") == "verify"]
    ev_rows = [[_when(e.get("time")), E(e.get("state") or ""), E(display_times(e.get("reason") or ""))]
               for e in hist["events"][-200:]]
    charts = "".join([
        trend_svg(tr["battery"], "battery at return", "%"),
        trend_svg(tr["drift"], "clock drift", "s/day"),
        trend_svg(tr["offset"], "calibration offset ± SE", "mg"),
        trend_svg(tr["gain"], "calibration gain − 1 ± SE", "%")])
    return (_head(f"stillpoint {key}", refresh_js=False)
            + f"<header><p><a href='/'>← dock</a></p><h1>{E(key)}</h1>"
            f"<p class=meta><a href='/device/{key}/sheet'>handover sheet</a></p></header>"
            + (f"<p class=msg>{E(message)}</p>" if message else "")
            + "<main id=deviceview><h2>Trends across sessions</h2>"
            f"<div class=charts>{charts}</div>"
            "<h2>Downloads and verification</h2>"
            + _table(["session", "state", "started (local / UTC)", "size", "SHA-256", "bad sectors",
                      "repairs", "battery", "clock offset", "calibration", "reason", "files"], dl_rows,
                     "no download yet")
            + "<h2>Verified again</h2>"
            + _table(["when", "result", "detail"],
                     [[_when(a.get("time")), E(a.get("result") or ""), E(a.get("reason") or "")]
                      for a in verifications], "not verified again from the dashboard")
            + "<h2>Clears</h2>"
            + _table(["when (local / UTC)", "session", "erase", "result", "reason", "read back"],
                     cl_rows, "never cleared")
            + "<h2>Configurations</h2>"
            + _table(["configured at (local / UTC)", "session", "subject", "settings", "battery",
                      "result", "warnings / reason"], cf_rows, "never configured")
            + "<h2>Actions asked for</h2>"
            + _table(["when", "action", "who", "from", "result", "reason"], ac_rows, "none")
            + "<details><summary>State changes</summary>"
            + _table(["when", "state", "reason"], ev_rows, "none") + "</details>"
            + "</main></body></html>")


def superseded(hist: dict) -> dict:
    """{configuration id: the configuration that superseded it}: a device configured again with
    no completed clear between the two configurations (the first sheet was never worn)."""
    ok_cfg = [c for c in hist["configurations"] if c.get("result") == "ok"]
    clears = [x.get("time") or 0 for x in hist["clears"] if x.get("result") == "ok"]
    out = {}
    for a, b in zip(ok_cfg, ok_cfg[1:]):
        if not any((a.get("time") or 0) < t < (b.get("time") or 0) for t in clears):
            out[a["id"]] = b
    return out


def sheet_page(hist: dict, *, file_name: Optional[str] = None,
               session: Optional[int] = None) -> Optional[str]:
    """The printable handover sheet: what was set on the device, when, and the checks; of the
    latest configuration, or of the latest one for ``session`` (None when there is none). A
    sheet whose configuration was superseded says so, and the sheet that superseded another
    names it."""
    key = device_key(hist["device_type"], hist["device_id"])
    ok_cfg = [c for c in hist["configurations"] if c.get("result") == "ok"]
    if session is not None:
        ok_cfg = [c for c in ok_cfg if (c.get("settings") or {}).get("session") == session]
        if not ok_cfg:
            return None
    c = ok_cfg[-1] if ok_cfg else None
    sup = superseded(hist)
    later = sup.get(c["id"]) if c is not None else None
    earlier = [a for a, b in sup.items() if c is not None and b["id"] == c["id"]]
    if later is not None:
        lloc, lutc = local_utc(later.get("time"))
        banner = (f"SUPERSEDED: this device was configured again as session "
                  f"{(later.get('settings') or {}).get('session', '-')} at {lloc} ({lutc}); "
                  "this sheet is void.")
    else:
        banner = None
    s = (c or {}).get("settings") or {}
    last_dl = [d for d in hist["downloads"] if d.get("state") == "verified"]
    last_clear = [x for x in hist["clears"] if x.get("result") == "ok"]
    loc, utc = local_utc((c or {}).get("time"))
    rows = [("Device", key), ("Subject", subject_of(c or {}) or "________________"),
            ("Session", s.get("session", "-")), ("Configured at (local)", loc),
            ("Configured at (UTC)", utc),
            ("Rate", f"{s['rate_hz']:g} Hz" if s.get("rate_hz") is not None else "-"),
            ("Range", f"±{s['range_g']} g" if s.get("range_g") is not None else "-"),
            ("Gyroscope", f"{s['gyro_dps']} °/s" if s.get("gyro_dps") else "off"),
            ("Recording starts", display_time(s["start"]) if s.get("start") is not None else "-"),
            ("Recording stops", display_time(s["stop"]) if s.get("stop") is not None else "-"),
            ("Battery at configure", f"{s['battery_pct']} %" if s.get("battery_pct") is not None else "-"),
            ("Clock offset after setting", f"{s['clock_offset_s']:+.3f} s"
             if s.get("clock_offset_s") is not None else "-"),
            ("Metadata", ", ".join(f"{k}={v}" for k, v in (s.get("metadata") or {}).items()) or "-")]
    if earlier:
        prev = next(x for x in hist["configurations"] if x["id"] == earlier[-1])
        ploc, _ = local_utc(prev.get("time"))
        rows.append(("Supersedes", f"the sheet of session "
                                   f"{(prev.get('settings') or {}).get('session', '-')} "
                                   f"(configured {ploc}): void"))
    if file_name and later is None:
        rows.append(("File name at return", file_name))
    checks = [
        ("Previous data downloaded and verified (size + SHA-256)",
         f"yes, session {last_dl[-1]['session_id']} ({(last_dl[-1].get('sha256') or '')[:16]})"
         if last_dl else "no verified download"),
        ("Cleared after verification", f"yes ({last_clear[-1].get('erase')})" if last_clear else "no"),
        ("Configured and read back", "yes" if c else "not configured"),
        ("Configuration warnings", display_times((c or {}).get("reason") or "none"))]
    body = "".join(f"<tr><th>{E(k)}</th><td>{E(str(v))}</td></tr>" for k, v in rows)
    chk = "".join(f"<tr><th>{E(k)}</th><td>{E(str(v))}</td></tr>" for k, v in checks)
    printed_loc, printed_utc = local_utc(time.time())
    return (_head(f"handover {key}")
            + "<main id=sheet class=sheet>"
            f"<p class=noprint><a href='/device/{key}'>← {E(key)}</a> · "
            "<button id=print>Print</button></p>"
            f"<h1>Device handover sheet — {E(key)}</h1>"
            + (f"<p class=msg id=superseded>{E(banner)}</p>" if banner else "")
            + f"<table class=kv>{body}</table>"
            f"<h2>Checks</h2><table class=kv>{chk}</table>"
            "<h2>Handover</h2><table class=kv><tr><th>Given to participant by</th><td></td></tr>"
            "<tr><th>Date and time</th><td></td></tr><tr><th>Signature</th><td></td></tr></table>"
            f"<p class=small>Printed {E(printed_loc)} ({E(printed_utc)}) from the station ledger.</p>"
            "</main></body></html>")


def message_page(status: int, message: str, back: str = "/") -> str:
    return (_head(f"{status}", refresh_js=False)
            + f"<main><h1>{status}</h1><p class=msg id=message>{E(message)}</p>"
            f"<p><a href='{E(back)}'>back</a></p></main></body></html>")


def sse_payload(fragment: str) -> bytes:
    return ("data: " + json.dumps({"html": fragment}) + "\n\n").encode()
