"""One-page visual report of a processed recording: ``write_report(mcap) -> {report, report_html}``.

A PNG page (and an HTML page embedding it with the day table) that a person looks at instead of
reading tables:

* **activity per local day**: ENMO per epoch (mg) against the local clock, one row per day, with
  nonwear (grey), clipping (red), QC-flagged data (orange) and gaps (hatched) shaded, the day's
  wear hours and valid-day mark at the right;
* with activity outcomes in the day table (``engine.outcomes``), each day's steps per Verisense
  parameter set and MVPA minutes of the cut-point set under its wear hours;
* **temperature** over the recording (degC, local time);
* **calibration**: the nonmovement windows' residuals ``|a| - 1`` (mg) before and after the
  applied estimate as histograms (windows beyond the axis range are counted, never dropped
  silently) and against each axis's mean value (the sphere seen from each axis, at mg scale);
* **QC box**: sectors/pages read and skipped, reader QC events, hours of nonwear/clipping/QC, valid
  days, calibration status and error, the time zone and nonwear rule.

Inputs: the MCAP (device, settings, summary and calibration records, the raw stream for the
window features) and the epoch/day tables beside it (made from the MCAP when missing, in a
temporary folder). matplotlib is an optional extra: ``require_matplotlib()`` says how to install
it before any work starts.
"""

from __future__ import annotations

import base64
import csv
import gzip
import html
import json
import tempfile
from pathlib import Path
from typing import Optional

import numpy as np

from stillpoint.engine.core.errors import StillpointError
from stillpoint.engine.core.figures import save_figure
from stillpoint.engine.core.outputs import atomic_output, check_output_path

from .calibration.estimate import status_applied

DAYS_SHOWN = 14
HIST_RANGE_MG = 60.0


class ReportUnavailableError(StillpointError):
    """matplotlib is not installed."""


def require_matplotlib():
    try:
        import matplotlib
    except ImportError:
        raise ReportUnavailableError(
            "the report needs matplotlib, an optional extra: pip install 'stillpoint[plot]' "
            "(or pip install matplotlib)") from None
    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    return plt


def report_paths(mcap) -> tuple[Path, Path]:
    p = Path(mcap)
    stem = p.name[:-5] if p.name.endswith(".mcap") else p.name
    return p.with_name(stem + ".report.png"), p.with_name(stem + ".report.html")


# ---------------------------------------------------------------------------- inputs
_FLAG_COLUMNS = ("nonwear", "clipping", "gap", "qc", "filter_warmup")
_SLEEP_COLUMNS = ("spt", "sib")  # present when the tables were written with sleep on
READ_ROWS = 1 << 15  # epoch rows parsed at once


def _read_epochs(path, days_shown: int = DAYS_SHOWN) -> dict:
    """What the page draws from the epoch table, read ``READ_ROWS`` rows at a time: every local
    date in order (``dates``); the rows of the first ``days_shown`` dates (``date``, ``hour``,
    ``enmo_mg`` and the flags); the finite temperatures with their local times (``temp_local``,
    ``temp_c``). Memory follows the days drawn, not the table's length (a month of 5 s epochs,
    or a clock that jumps a year, is millions of rows)."""
    dates: dict[str, None] = {}
    parts: dict[str, list] = {k: [] for k in ("date", "hour", "enmo_mg", "temp_local", "temp_c",
                                               *_FLAG_COLUMNS, *_SLEEP_COLUMNS)}

    def num(col):
        return np.array([float(x) if x else np.nan for x in col])

    def take(rows):
        cols = dict(zip(header, zip(*rows)))
        local = np.array([x[:19] for x in cols["time_local"]], "M8[s]")
        date = np.datetime_as_string(local.astype("M8[D]"))
        for d in dict.fromkeys(date.tolist()):
            dates.setdefault(d)
        temp = num(cols["temperature_c"])
        ok = np.isfinite(temp)
        parts["temp_local"].append(local[ok])
        parts["temp_c"].append(temp[ok])
        shown = set(list(dates)[:days_shown])
        keep = np.isin(date, list(shown))
        if not keep.any():
            return
        sec = (local - local.astype("M8[D]")).astype(np.int64)[keep]
        parts["date"].append(date[keep])
        parts["hour"].append(sec / 3600.0)
        parts["enmo_mg"].append(num(cols["enmo_mg"])[keep])
        for k in _FLAG_COLUMNS:
            parts[k].append(np.array([x == "1" for x in cols[k]])[keep])
        for k in _SLEEP_COLUMNS:  # tables written with sleep on (engine/sleep)
            v = cols.get(k)
            parts[k].append((np.array([x == "1" for x in v]) if v else np.zeros(local.shape, bool))[keep])

    with gzip.open(path, "rt", newline="") as f:
        reader = csv.reader(f)
        header = next(reader, [])
        rows = []
        for r in reader:
            rows.append(r)
            if len(rows) == READ_ROWS:
                take(rows)
                rows = []
        if rows:
            take(rows)
    empty = {"date": np.zeros(0, "U10"), "hour": np.zeros(0), "enmo_mg": np.zeros(0),
             "temp_local": np.zeros(0, "M8[s]"), "temp_c": np.zeros(0),
             **{k: np.zeros(0, bool) for k in _FLAG_COLUMNS + _SLEEP_COLUMNS}}
    d = {k: np.concatenate(v) if v else empty[k] for k, v in parts.items()}
    d["dates"] = list(dates)
    return d


def _read_days(path) -> list[dict]:
    with open(path) as f:
        return list(csv.DictReader(f))


def _sphere(mcap, est_json: Optional[dict], settings: dict, progress=None):
    """Nonmovement window means (raw g), temperatures, and the estimate to apply."""
    from stillpoint.engine.mcap.replay import McapRawSource
    from .calibration.estimate import CalibrationEstimate
    from .operators.nonmovement import NonmovementOperator
    from .operators.windows import WindowFeaturesOperator

    src = McapRawSource(mcap)
    try:
        rate = float(src.info.sample_rate_nominal or 0) or 100.0
        win = WindowFeaturesOperator(rate, settings.get("window_s", 10.0), settings.get("min_fill", 0.9))
        kw = {}
        if "sd_threshold_g" in settings:
            kw["sd_threshold"] = settings["sd_threshold_g"]
        nm = NonmovementOperator(**kw)
        from .core.blocks import coalesce_blocks
        for b in coalesce_blocks(src):  # 10-min blocks instead of the log's 10-s messages
            nm.push(win.push(b))
            if progress is not None and callable(getattr(src, "progress", None)):
                progress.update(fraction=src.progress())
        nm.push(win.flush())
    finally:
        src.close()
    w = nm.selected
    est = CalibrationEstimate.from_dict(est_json) if est_json else None
    return w, est


def _mcap_records(mcap) -> dict:
    from stillpoint.engine.mcap.replay import McapRawSource
    src = McapRawSource(mcap)
    meta = dict(src.metadata)
    src.close()
    out = {}
    for name in ("summary", "calibration", "settings", "device"):
        m = meta.get(name)
        if not m:
            continue
        try:
            out[name] = json.loads(m["json"]) if "json" in m else {k: _maybe_json(v) for k, v in m.items()}
        except (ValueError, TypeError):
            out[name] = dict(m)
    return out


def _maybe_json(v):
    try:
        return json.loads(v)
    except (ValueError, TypeError):
        return v


# ---------------------------------------------------------------------------- drawing
def _shade(ax, hour, mask, color, label, hatch=None, step_h=5 / 3600):
    if not mask.any():
        return
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    for s, e in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)):
        ax.axvspan(hour[s], hour[e - 1] + step_h, color=color, alpha=0.35 if not hatch else 0.15,
                   lw=0, hatch=hatch, label=label)
        label = None


def _sleep_marks(ax, hour, spt, sib, ymax, step_h):
    """A night's sleep period (light band) and its sustained inactivity bouts (bars at the foot)."""
    for mask, kind in ((spt, "spt"), (sib, "sib")):
        if not mask.any():
            continue
        d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
        for s, e in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)):
            a, b = hour[s], hour[e - 1] + step_h
            if kind == "spt":
                ax.axvspan(a, b, color="tab:cyan", alpha=0.25, lw=0)
            else:
                ax.plot([a, b], [ymax * 0.02] * 2, color="tab:blue", lw=2.5, solid_capstyle="butt")


def _outcome_text(day: dict) -> str:
    """MVPA minutes and steps of a day row (the Verisense sets' counts joined by `` / ``, in the
    table's order), one line each; empty without those columns."""
    out = []
    mvpa = [v for k, v in day.items() if k.startswith("min_mvpa_") and v not in (None, "")]
    if mvpa:
        out.append(f"MVPA {float(mvpa[0]):.0f} min")
    steps = [f"{int(float(v)):,}" for k, v in day.items()
             if k.startswith("steps_verisense_") and v not in (None, "")]
    if steps:
        out.append("steps " + " / ".join(steps))
    return "".join("\n" + x for x in out)


def _clock_label(hour: float, _pos=None) -> str:
    """Hours since local midnight as a clock time (``13:30``; 24 h as ``24:00``)."""
    m = int(round(hour * 60))
    return f"{m // 60:02d}:{m % 60:02d}"


def _clock_ticks(h0: float, h1: float) -> np.ndarray:
    """Clock-time ticks over a span of hours: every 3 h for a day, finer for a short span
    (15 min, 30 min, 1 h or 2 h steps), about 4-10 ticks."""
    span = h1 - h0
    step = next((s for s in (0.25, 0.5, 1.0, 2.0) if span / s <= 10), 3.0)
    return np.arange(np.ceil(h0 / step) * step, h1 + 1e-9, step)


def _qc_lines(rec: dict, days: list[dict]) -> int:
    return _qc_text(rec, days).count("\n") + 1


def _draw(plt, ep: dict, days: list[dict], windows, est, rec: dict, title: str, epoch_s: float):
    fig = plt.figure(figsize=(8.27, 11.69), dpi=110)
    dates = ep["dates"]
    shown = dates[:DAYS_SHOWN]
    n_day = max(len(shown), 1)
    day_h = 1.0 if n_day > 4 else 1.4
    qc_h = max(1.2, 0.16 * _qc_lines(rec, days))  # the QC box grows with its (wrapped) lines
    gs = fig.add_gridspec(n_day + 6, 4, height_ratios=[day_h] * n_day + [0.55, 1.3, 0.35, 1.8, 0.3, qc_h],
                          hspace=0.25, wspace=0.45, left=0.08, right=0.88, top=0.91, bottom=0.03)
    fig.suptitle(title, fontsize=9.5)
    step_h = epoch_s / 3600
    by_date = {d["date"]: d for d in days}
    ymax = 300.0
    from .timezones import UNKNOWN_LABEL
    # times are local only when the zone is known; otherwise they are the device clock
    device_clock = bool(days) and days[-1].get("timezone") == UNKNOWN_LABEL
    clock = "device clock (zone unknown)" if device_clock else "local time"
    short = len(dates) == 1 and len(ep["hour"]) and (ep["hour"][-1] - ep["hour"][0]) < 6
    if short:
        pad = max(0.02, 0.05 * (ep["hour"][-1] - ep["hour"][0]))
        h0, h1 = ep["hour"][0] - pad, ep["hour"][-1] + step_h + pad
    for i, date in enumerate(shown):
        ax = fig.add_subplot(gs[i, :])
        sel = ep["date"] == date
        h, e = ep["hour"][sel], ep["enmo_mg"][sel]
        _shade(ax, h, ep["nonwear"][sel], "0.55", "nonwear", step_h=step_h)
        _shade(ax, h, ep["clipping"][sel], "tab:red", "clipping", step_h=step_h)
        _shade(ax, h, ep["qc"][sel], "tab:orange", "QC-flagged", step_h=step_h)
        _shade(ax, h, ep["gap"][sel], "tab:blue", "gap (no data)", hatch="///", step_h=step_h)
        if "spt" in ep:
            _sleep_marks(ax, h, ep["spt"][sel], ep["sib"][sel], ymax, step_h)
        ax.plot(h, np.minimum(e, ymax), lw=0.5, color="k", label="ENMO")
        over = e > ymax
        if over.any():
            ax.plot(h[over], np.full(over.sum(), ymax), "|", ms=3, color="tab:purple",
                    label=f"ENMO > {ymax:.0f} mg")
        ax.set_ylim(0, ymax * 1.05)
        if short:  # a recording of a few hours: show its span, not the whole day
            ax.set_xlim(h0, h1)
            ax.set_xticks(_clock_ticks(h0, h1))
        else:
            ax.set_xlim(0, 24)
            ax.set_xticks(range(0, 25, 3))
        ax.xaxis.set_major_formatter(_clock_label)
        ax.tick_params(labelsize=6.5, length=2)
        if i < len(shown) - 1:
            ax.set_xticklabels([])
        ax.set_ylabel(date[5:], fontsize=7, rotation=0, ha="right", va="center")
        d = by_date.get(date)
        if d:
            mark = "valid" if d.get("valid_day") == "1" else "not valid"
            if float(d.get("day_hours") or 24) != 24:
                mark += f"\n({float(d['day_hours']):g}-h day)"
            wh = float(d["wear_hours"])
            more = _outcome_text(d)  # smaller type: the lines fit the row of a 14-day page
            ax.text(1.01, 0.5, (f"{wh:.1f} h" if wh >= 1 else f"{wh * 60:.1f} min") + f" wear\n{mark}"
                    + more, transform=ax.transAxes, fontsize=5.5 if more else 6.5, va="center")
        if i == 0:
            ax.set_title(f"ENMO per epoch (mg) against the {clock}, one row per "
                         f"{'device-clock' if device_clock else 'local'} day", fontsize=8, pad=14)
    if len(dates) > DAYS_SHOWN:
        fig.text(0.5, 0.945, f"first {DAYS_SHOWN} of {len(dates)} days shown", ha="center", fontsize=7)
    if shown:
        fig.axes[len(shown) - 1].set_xlabel(clock, fontsize=7, labelpad=1)
    # legend entries for every shading kind, present or not
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    handles = [Line2D([], [], color="k", lw=0.8, label="ENMO"),
               Line2D([], [], color="tab:purple", marker="|", ls="", label=f"ENMO > {ymax:.0f} mg (cut)"),
               Patch(color="0.55", alpha=0.35, label="nonwear"),
               Patch(color="tab:red", alpha=0.35, label="clipping"),
               Patch(color="tab:orange", alpha=0.35, label="QC-flagged"),
               Patch(facecolor="none", edgecolor="tab:blue", hatch="///", label="gap (no data)")]
    if "spt" in ep and (ep["spt"].any() or ep["sib"].any()):
        handles += [Patch(color="tab:cyan", alpha=0.25, label="sleep period"),
                    Line2D([], [], color="tab:blue", lw=2.5, label="inactivity bout")]
    if fig.axes:
        fig.axes[0].legend(handles=handles, fontsize=6 if len(handles) <= 6 else 5.2,
                           ncol=len(handles), loc="lower left", frameon=False,
                           bbox_to_anchor=(0, 1.0), borderaxespad=0.1)
    # temperature
    ax = fig.add_subplot(gs[n_day + 1, :])
    if len(ep["temp_c"]):
        ax.plot(ep["temp_local"], ep["temp_c"], lw=0.6, color="tab:red")
    ax.set_ylabel("degC", fontsize=7)
    ax.set_title(f"device temperature ({clock})", fontsize=8)
    ax.tick_params(labelsize=6.5)
    import matplotlib.dates as mdates
    loc = mdates.AutoDateLocator(maxticks=9)
    ax.xaxis.set_major_locator(loc)
    fmt = mdates.ConciseDateFormatter(loc)
    fmt.offset_formats = [""] * 6  # the dates are on the ticks already
    ax.xaxis.set_major_formatter(fmt)
    # calibration
    _calibration_panels(fig, gs[n_day + 3, :], windows, est)
    # QC box
    ax = fig.add_subplot(gs[n_day + 5, :])
    ax.axis("off")
    ax.text(0.0, 1.0, _qc_text(rec, days), fontsize=7, va="top", family="monospace",
            transform=ax.transAxes)
    return fig


def _calibration_panels(fig, spec, windows, est):
    sub = spec.subgridspec(1, 4, wspace=0.45)
    ax = fig.add_subplot(sub[0, 0])
    if windows is None or not len(windows):
        ax.axis("off")
        ax.text(0, 0.5, "calibration: no nonmovement windows", fontsize=7)
        return
    before = (np.linalg.norm(windows.mean, axis=1) - 1.0) * 1000.0
    if est is not None and est.applied:
        t = windows.temperature
        if est.uses_temperature:
            t = np.where(np.isfinite(t), t, est.temperature_ref)
            cal = est.apply(windows.mean, t)
        else:
            cal = est.apply(windows.mean)
        after = (np.linalg.norm(cal, axis=1) - 1.0) * 1000.0
        after_label = "after"
    else:
        after, after_label = None, f"not applied ({est.status if est else 'no estimate'})"
    r = HIST_RANGE_MG
    bins = np.linspace(-r, r, 61)
    for vals, color, lab in ((before, "0.5", "before"), (after, "tab:blue", after_label)):
        if vals is None:
            continue
        off = int((np.abs(vals) > r).sum())
        ax.hist(np.clip(vals, -r, r), bins=bins, color=color, alpha=0.6,
                label=f"{lab}\nRMS {np.sqrt(np.mean(vals ** 2)):.1f} mg" +
                      (f", {off} in\nend bins (beyond +-{r:.0f})" if off else ""))
    ax.set_xlabel("|a| - 1 (mg)", fontsize=7)
    ax.set_ylabel("windows", fontsize=7)
    ax.set_title(f"{len(before):,} nonmovement windows", fontsize=7.5)
    ax.tick_params(labelsize=6.5)
    ax.set_ylim(top=ax.get_ylim()[1] * 1.9)  # room for the legend above the bars
    from matplotlib.ticker import MaxNLocator
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))  # window counts
    ax.legend(fontsize=5, loc="upper left", frameon=False, handlelength=1.0, handletextpad=0.4,
              borderaxespad=0.2, labelspacing=0.3)
    lim = max(r, float(np.percentile(np.abs(before), 99)) * 1.1)
    for j, name in enumerate("xyz"):
        a = fig.add_subplot(sub[0, j + 1])
        a.scatter(windows.mean[:, j], before, s=2, c="0.5", alpha=0.5, lw=0, label="before")
        if after is not None:
            a.scatter(windows.mean[:, j], after, s=2, c="tab:blue", alpha=0.6, lw=0, label="after")
        a.axhline(0, color="k", lw=0.5)
        a.set_ylim(-lim, lim)
        a.set_xlim(-1.1, 1.1)
        a.set_xlabel(f"mean {name} (g)", fontsize=7)
        if j == 0:
            a.set_ylabel("|a| - 1 (mg)", fontsize=7)
        a.tick_params(labelsize=6.5)
        a.set_title(f"residual against {name}", fontsize=7.5)


def _qc_text(rec: dict, days: list[dict]) -> str:
    s = rec.get("summary") or {}
    cal = s.get("calibration") or rec.get("calibration") or {}
    qc = s.get("qc") or {}
    total = next((d for d in days if d["date"] == "all"), {})
    dev = s.get("device") or {}
    def f(x, fmt="{:.2f}"):
        try:
            return fmt.format(float(x))
        except (TypeError, ValueError):
            return "n/a"
    unit = qc.get("unit", "sector")
    reasons = ", ".join(f"{k} {v}" for k, v in (qc.get("reasons") or {}).items()) or "none"
    errors = f"{f(cal.get('error_before_mg'), '{:.2f}')} -> {f(cal.get('error_after_mg'), '{:.2f}')} mg"
    lines = [
        f"device {dev.get('type', '?')} {dev.get('id', '?')}, {f(dev.get('rate_hz'), '{:g}')} Hz, "
        f"+-{f(dev.get('range_g'), '{:g}')} g     times: {total.get('timezone', '?')}",
        f"{unit}s: {qc.get('total', '?')} read, {qc.get('skipped', '?')} skipped; "
        f"segments {s.get('segments', '?')}; reader QC events: {reasons}",
        f"hours: recorded {f(total.get('recorded_hours'))}, data {f(total.get('data_hours'))}, "
        f"clean wear {f(total.get('wear_hours'))}, nonwear {f(total.get('nonwear_hours'))}, "
        f"clipping {f(total.get('clipping_hours'))}, QC-flagged {f(total.get('qc_hours'))}",
        f"valid days (>= 16 h clean wear by default): {total.get('valid_day', '?')} of "
        f"{len([d for d in days if d['date'] != 'all'])}; mean ENMO over clean epochs "
        f"{f(total.get('enmo_mean_mg'), '{:.2f}')} mg",
        f"calibration: {cal.get('status', '?')}"
        + ("" if errors in str(cal.get("reason", "")) else  # the reason says it already
           f" - error {errors} on {cal.get('windows', '?')} windows")
        + (f", T_ref {cal['temperature_ref']:.2f} degC" if status_applied(cal.get("status"))
           and cal.get("temperature_ref") is not None and any(cal.get("tempoffset") or []) else ""),
    ]
    reason = str(cal.get("reason", ""))
    if reason:
        import textwrap
        lines += ["  " + x for x in textwrap.wrap(reason, 104)]  # in full, never cut
    sets = [k[len("steps_verisense_"):] for k in total if k.startswith("steps_verisense_")]
    if sets:
        lines.append("steps per day (Verisense algorithm): " + " / ".join(sets) + " parameters")
    return "\n".join(lines)


# ---------------------------------------------------------------------------- the job
def write_report(mcap, *, summary: Optional[dict] = None, out_png=None, out_html=None,
                 progress=None) -> dict:
    """Write the PNG page and the HTML page for a processed recording's MCAP. ``progress``: an
    ``engine.progress.Progress`` told of the three steps (tables, the calibration sphere read
    from the raw stream, drawing)."""
    plt = require_matplotlib()
    mcap = Path(mcap)
    png, page = report_paths(mcap)
    png, page = Path(out_png or png), Path(out_html or page)
    check_output_path(png, what="report")
    check_output_path(page, what="report page")
    from .tables import table_paths
    from .workflows.tables_from_mcap import tables_from_mcap
    ep_path, days_path = table_paths(mcap)
    rec = _mcap_records(mcap)
    if summary:
        rec["summary"] = summary
    settings = rec.get("settings") or {}
    with tempfile.TemporaryDirectory(prefix=".report-", dir=str(png.parent)) as tmp:
        if progress is not None:
            progress.phase(0, 3)
            progress.update(fraction=0.0, detail="tables")
        if not (ep_path.is_file() and days_path.is_file()):
            ep_path = Path(tmp) / "t.epochs.csv.gz"
            days_path = Path(tmp) / "t.days.csv"
            tables_from_mcap(mcap, ep_path, days_path)
        ep = _read_epochs(ep_path)
        days = _read_days(days_path)
    est_json = (rec.get("summary") or {}).get("calibration") or rec.get("calibration")
    if progress is not None:
        progress.phase(1, 3)
        progress.update(fraction=0.0, detail="nonmovement windows")
    windows, est = _sphere(mcap, est_json, settings, progress)
    if progress is not None:
        progress.phase(2, 3)
        progress.update(fraction=0.0, detail="drawing")
    dev = (rec.get("summary") or {}).get("device") or {}
    title = (f"{mcap.name}: {dev.get('type', '')} {dev.get('id', '')}, "
             f"{ep['dates'][0] if ep['dates'] else '?'} to {ep['dates'][-1] if ep['dates'] else '?'}")
    fig = _draw(plt, ep, days, windows, est, rec, title, float(settings.get("epoch_s", 5.0)))
    save_figure(fig, png, dpi="figure", fmt="png")
    plt.close(fig)
    data = base64.b64encode(png.read_bytes()).decode()
    cols = list(days[0].keys()) if days else []
    table = "".join("<tr>" + "".join(f"<td>{html.escape(str(d[c]))}</td>" for c in cols) + "</tr>"
                    for d in days)
    doc = (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(mcap.name)}</title>"
           "<style>body{font-family:sans-serif;font-size:13px}td,th{padding:2px 6px;"
           "border-bottom:1px solid #ddd}</style></head><body>"
           f"<h2>{html.escape(title)}</h2><img src='data:image/png;base64,{data}' "
           "style='max-width:100%' alt='recording report'>"
           "<h3>days</h3><table><tr>" + "".join(f"<th>{html.escape(str(c))}</th>" for c in cols) +
           f"</tr>{table}</table></body></html>\n")
    with atomic_output(page, binary=False) as f:
        f.write(doc)
    return {"report": str(png), "report_html": str(page)}
