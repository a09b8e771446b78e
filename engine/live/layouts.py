"""Foxglove layouts generated from a topic list: one for a processed recording, one for the
station (a tab per device). Plain JSON in the layout format Foxglove imports ("Import from
file..." in the Layouts menu): ``configById`` (one config per panel id ``<Kind>!<name>``) and
``layout`` (a tree of row/column splits whose leaves are panel ids); the format of Foxglove's own
layout export (docs.foxglove.dev/docs/visualization/layouts; the panel configs as the typed layout
builder of foxglove-sdk, ``foxglove.layouts``, spells them, written here as plain JSON).

Panels follow from each topic's schema:

* a CDR topic whose fields are all scalars (``/view/accel``, ``/metrics/epoch``,
  ``/temperature``) is plotted; its ``*_mg`` fields share one plot, temperatures (``celsius``,
  ``temperature_c``, from every topic) another, and its other numeric fields (counts such as
  ``n`` aside) a third. Batched topics (array fields: ``/raw/accel``, ``/corrected/accel``)
  are not plotted: a plot cannot place a batch's samples in time (``/view/accel`` exists for that);
* a JSON topic whose name ends in ``/state`` gets a State Transitions panel on its ``state``;
  one ending in ``/progress``, ``/battery``, ``/clock_offset`` or ``/preview/corrected`` is
  plotted (its numeric JSON-schema properties but times, ``*_ns``); every other JSON topic (``/calibration``, ``/qc``) gets a Raw Messages
  panel.

Nothing here needs the ``live`` extra: ``stillpoint view --layout`` writes a layout without it.
"""

from __future__ import annotations

import json
import re
from typing import Iterable, NamedTuple, Optional

COUNT_FIELDS = {"n"}
TIME_SUFFIXES = ("_ns",)  # times are the plot's x axis, not a line in it  # sample counts: not worth a line in a plot
TEMPERATURE_FIELDS = {"celsius", "temperature_c"}
PLOTTED_JSON = ("/progress", "/battery", "/clock_offset", "/preview/corrected")
_NUMERIC_ROS = {"int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64",
                "float32", "float64"}


class Topic(NamedTuple):
    """A topic as a layout sees it (``ChannelInfo`` of engine/mcap/stream.py fits)."""
    topic: str
    message_encoding: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes


def numeric_fields(t: Topic) -> Optional[list[str]]:
    """The scalar numeric fields of a topic's messages, in schema order; None when the messages
    are batches (a field is an array) or the schema is not one we read."""
    if t.schema_encoding == "ros2msg":
        fields = []
        text = bytes(t.schema_data).decode("utf-8", "replace").split("=" * 80)[0]
        for line in text.splitlines():
            line = line.split("#", 1)[0].strip()
            if not line:
                continue
            kind, _, name = line.partition(" ")
            if kind.endswith("]"):
                return None
            if kind in _NUMERIC_ROS:
                fields.append(name.strip())
        return fields
    if t.schema_encoding == "jsonschema":
        try:
            doc = json.loads(bytes(t.schema_data).decode("utf-8"))
        except ValueError:
            return None
        out = []
        for name, p in (doc.get("properties") or {}).items():
            kinds = p.get("type") if isinstance(p, dict) else None
            kinds = kinds if isinstance(kinds, list) else [kinds]
            if "number" in kinds or "integer" in kinds:
                out.append(name)
        return out
    return None


def _slug(s: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", s).strip("_") or "root"


def _plot(title: str, paths: list[tuple[str, str]]) -> dict:
    return {"title": title,
            "paths": [{"value": v, "enabled": True, "timestampMethod": "receiveTime", "label": label}
                      for v, label in paths],
            "showXAxisLabels": True, "showYAxisLabels": True, "showLegend": True,
            "legendDisplay": "floating", "showPlotValuesInLegend": True, "isSynced": True,
            "xAxisVal": "timestamp", "sidebarDimension": 240}


def _split(ids: list, direction: str):
    """A balanced tree of splits over ``ids`` (a single id is a leaf)."""
    if not ids:
        return None
    if len(ids) == 1:
        return ids[0]
    k = len(ids) // 2
    return {"direction": direction, "first": _split(ids[:k], direction),
            "second": _split(ids[k:], direction), "splitPercentage": round(100 * k / len(ids))}


def panels(topics: Iterable[Topic], prefix: str = "") -> tuple[dict, list[str], list[str]]:
    """(configById, plot-like panel ids, raw-message panel ids) of ``topics``; ``prefix`` keeps
    panel ids unique when several devices share one layout."""
    config: dict = {}
    plots: list[str] = []
    raws: list[str] = []
    temps: list[tuple[str, str]] = []
    for t in topics:
        name = _slug(t.topic[len(prefix):] if prefix and t.topic.startswith(prefix) else t.topic)
        pid = _slug(prefix) + "_" + name if prefix else name
        short = t.topic[len(prefix):] if prefix and t.topic.startswith(prefix) else t.topic
        if t.message_encoding == "json":
            if t.topic.endswith("/state"):
                config[f"StateTransitions!{pid}"] = {
                    "paths": [{"value": f"{t.topic}.state", "timestampMethod": "receiveTime",
                               "label": "state"}], "isSynced": True}
                plots.append(f"StateTransitions!{pid}")
                continue
            fields = numeric_fields(t) if t.topic.endswith(PLOTTED_JSON) else None
            fields = [f for f in fields or () if not f.endswith(TIME_SUFFIXES)]
            if fields:
                config[f"Plot!{pid}"] = _plot(short.strip("/"), [(f"{t.topic}.{f}", f) for f in fields])
                plots.append(f"Plot!{pid}")
                continue
            config[f"RawMessages!{pid}"] = {"topicPath": t.topic}
            raws.append(f"RawMessages!{pid}")
            continue
        fields = numeric_fields(t)
        if not fields:
            continue  # batches: not plottable against time
        mg = [f for f in fields if f.endswith("_mg")]
        temps += [(f"{t.topic}.{f}", f"{short} {f}") for f in fields if f in TEMPERATURE_FIELDS]
        rest = [f for f in fields if f not in mg and f not in TEMPERATURE_FIELDS and f not in COUNT_FIELDS]
        if rest:
            config[f"Plot!{pid}"] = _plot(short.strip("/"), [(f"{t.topic}.{f}", f) for f in rest])
            plots.append(f"Plot!{pid}")
        if mg:
            config[f"Plot!{pid}_mg"] = _plot(f"{short.strip('/')} (mg)", [(f"{t.topic}.{f}", f[:-3]) for f in mg])
            plots.append(f"Plot!{pid}_mg")
    if temps:
        tid = f"Plot!{_slug(prefix) + '_' if prefix else ''}temperature_degC"
        config[tid] = _plot("Temperature (degC)", temps)
        plots.append(tid)
    return config, plots, raws


def _tree(plots: list[str], raws: list[str]):
    left, right = _split(plots, "column"), _split(raws, "column")
    if left is None or right is None:
        return left or right
    return {"direction": "row", "first": left, "second": right, "splitPercentage": 62}


def _document(config: dict, tree) -> dict:
    return {"configById": config, "globalVariables": {}, "userNodes": {}, "linkedGlobalVariables": [],
            "playbackConfig": {"speed": 1}, "layout": tree}


def recording_layout(topics: Iterable[Topic]) -> dict:
    """The layout of a processed recording's log (the view of the corrected stream on top)."""
    config, plots, raws = panels(topics)
    plots.sort(key=lambda pid: "view" not in pid)
    return _document(config, _tree(plots, raws))


def station_layout(devices: dict[str, list[Topic]]) -> dict:
    """The station's layout: one tab per device (``{device key: its topics}``, topics under
    ``/device/<key>/``)."""
    config: dict = {}
    tabs = []
    for key, topics in devices.items():
        c, plots, raws = panels(topics, prefix=f"/device/{key}/")
        config.update(c)
        tabs.append({"title": key, "layout": _tree(plots, raws)})
    if not tabs:
        return _document({}, None)
    config["Tab!devices"] = {"activeTabIdx": 0, "tabs": tabs}
    return _document(config, "Tab!devices")


def layout_json(layout: dict) -> str:
    return json.dumps(layout, indent=2) + "\n"
