"""Plot layouts for the node's topics: a Foxglove layout (JSON) and a PlotJuggler layout (XML) for a config.

Both draw, per SISO channel, the Bode magnitude and phase (measured against the model), the coherence and
epsilon(w) from ``<node>/<channel>/frequency_response`` (:mod:`gap_validation.core.plottable`,
docs/NODE_TOPICS.md), the channel's verdict from ``<node>/<channel>/verdict``, and ``/diagnostics``.

- **Foxglove**: Plot panels with the x axis "Path (current)" (``xAxisVal: currentCustom``): the latest
  message's log10-frequency row against its curve rows, as message-path slices ``.data[a:b]`` (inclusive). The
  verdict in a Raw Messages panel; ``/diagnostics`` in the Diagnostics summary and detail panels. One tab per
  channel.
- **PlotJuggler**: PlotJuggler flattens an array into one time series per element (``.../data[12]``), so a
  Reactive Script (Lua, run at the time cursor) gathers the elements of each row at the cursor into XY series
  ``<channel>/bode/<curve>`` (x: log10 frequency), which XY plots draw. Its streamer's *maximum array size*
  must be at least the table's size (11 rows x the grid).

The indices come from :data:`~gap_validation.core.plottable.CURVES` and the channel's grid size, so a layout
made for a config stays valid all flight long (the grid is fixed for a config). ``gap-validate layouts
--config CFG`` writes both for any config; ``config/foxglove_layout.json`` and
``config/plotjuggler_layout.xml`` are those of the bundled config.
"""
from __future__ import annotations

import hashlib
import json
import re
import xml.etree.ElementTree as ET
from typing import Any, Mapping, Sequence

import numpy as np

from gap_validation.core.plottable import CURVES, topic_token

__all__ = ["row_slice", "foxglove_layout", "foxglove_json", "plotjuggler_layout", "plotted_channels",
           "DEFAULT_NODE", "BODE_PLOTS", "foxglove_plots", "plotjuggler_series"]

#: Node name the layouts address by default (the node's ``NODE_NAME``).
DEFAULT_NODE = "/gap_validator"

#: The plots of a channel: title -> (y curves, y axis label). x is always the log10 frequency.
BODE_PLOTS = {
    "magnitude": (("measured_magnitude_db", "model_magnitude_db"), "dB"),
    "phase": (("measured_phase_deg", "model_phase_deg"), "deg"),
    "coherence and epsilon": (("coherence", "epsilon"), "-"),
}
_X = "log10_frequency_rad_s"
_COLORS = {
    "measured_magnitude_db": "#1f77b4",
    "measured_phase_deg": "#1f77b4",
    "model_magnitude_db": "#d62728",
    "model_phase_deg": "#d62728",
    "coherence": "#2ca02c",
    "epsilon": "#ff7f0e",
}
_LABELS = {
    "measured_magnitude_db": "measured",
    "measured_phase_deg": "measured",
    "model_magnitude_db": "model",
    "model_phase_deg": "model",
    "coherence": "coherence",
    "epsilon": "epsilon(w)",
}


def row_slice(curve: str, n: int) -> tuple[int, int]:
    """The first and last index (inclusive, as message-path slices) of a curve's row in the table's ``data``.

    Parameters
    ----------
    curve : str
        A name of :data:`~gap_validation.core.plottable.CURVES`.
    n : int
        The channel's grid size (frequencies).
    """
    k = CURVES.index(curve)
    return k * n, k * n + n - 1


def plotted_channels(config) -> list[tuple[str, str, int]]:
    """The SISO channels a layout draws: ``(name, topic token, grid size)``; MIMO channels have no table.

    Parameters
    ----------
    config : ValidationConfig
        The validation config.
    """
    return [(name, topic_token(name), int(ch.frequencies.count)) for name, ch in config.channels.items()
            if not getattr(ch, "is_mimo", False)]


def _node(node: str) -> str:
    return "/" + node.strip("/")


def _id(kind: str, *parts: str) -> str:
    """A stable panel id (Foxglove ids are ``Type!suffix``)."""
    return f"{kind}!" + hashlib.blake2b("/".join(parts).encode(), digest_size=5).hexdigest()


def _split(items: list[Any], direction: str) -> Any:
    """A Foxglove mosaic tree splitting ``items`` evenly along ``direction``."""
    if len(items) == 1:
        return items[0]
    half = len(items) // 2
    return {"first": _split(items[:half], direction), "second": _split(items[half:], direction),
            "direction": direction, "splitPercentage": round(100.0 * half / len(items), 3)}


def foxglove_layout(config, node: str = DEFAULT_NODE) -> dict:
    """The Foxglove layout (the JSON of *Export layout*) for a config's channels.

    Parameters
    ----------
    config : ValidationConfig
        The channels (names and grid sizes) to draw.
    node : str
        The node's fully qualified name (``/gap_validator``; with a namespace ``/ns/gap_validator``).

    Returns
    -------
    dict
        ``configById``, ``globalVariables``, ``userNodes``, ``playbackConfig`` and ``layout`` (one tab per
        channel, then a diagnostics tab).
    """
    node = _node(node)
    panels: dict[str, Any] = {}
    tabs = []
    for name, token, n in plotted_channels(config):
        topic = f"{node}/{token}/frequency_response"
        x0, x1 = row_slice(_X, n)
        plots = []
        for title, (curves, unit) in BODE_PLOTS.items():
            pid = _id("Plot", node, token, title)
            panels[pid] = {
                "foxglovePanelTitle": f"{name}: {title}",
                "paths": [
                    {
                        "value": f"{topic}.data[{a}:{b}]",
                        "enabled": True,
                        "timestampMethod": "receiveTime",
                        "label": _LABELS[c],
                        "color": _COLORS[c],
                        "showLine": True,
                    }
                    for c in curves
                    for a, b in [row_slice(c, n)]
                ],
                "xAxisVal": "currentCustom",
                "xAxisPath": {"value": f"{topic}.data[{x0}:{x1}]", "enabled": True},
                "xAxisName": "log10 frequency [rad/s]",
                "yAxisName": unit,
                "showLegend": True,
                "legendDisplay": "top",
                "showPlotValuesInLegend": False,
                "showXAxisLabels": True,
                "showYAxisLabels": True,
                "isSynced": False,
                "sidebarDimension": 240,
            }
            plots.append(pid)
        verdict = _id("RawMessages", node, token)
        panels[verdict] = {
            "foxglovePanelTitle": f"{name}: verdict",
            "topicPath": f"{node}/{token}/verdict.data",
            "diffEnabled": False,
            "diffMethod": "custom",
            "diffTopicPath": "",
            "showFullMessageForDiff": False,
        }
        tabs.append({"title": name, "layout": {"first": _split(plots, "column"), "second": verdict,
                                               "direction": "row", "splitPercentage": 70}})
    summary, detail = _id("DiagnosticSummary", node), _id("DiagnosticStatusPanel", node)
    panels[summary] = {
        "topicToRender": "/diagnostics",
        "minLevel": 0,
        "pinnedIds": [],
        "hardwareIdFilter": "",
        "sortByLevel": True,
    }
    panels[detail] = {"topicToRender": "/diagnostics", "collapsedSections": [], "selectedHardwareId": "",
                      "splitFraction": 0.5}
    tabs.append({"title": "diagnostics", "layout": {"first": summary, "second": detail, "direction": "row",
                                                    "splitPercentage": 40}})
    tab = _id("Tab", node, "channels")
    panels[tab] = {"activeTabIdx": 0, "tabs": tabs}
    return {"configById": panels, "globalVariables": {}, "userNodes": {}, "playbackConfig": {"speed": 1.0},
            "layout": tab}


def _lua(config, node: str) -> tuple[str, str]:
    """The reactive script: its global code (the XY series and the rows' first indices) and its function."""
    rows = []
    for name, token, n in plotted_channels(config):
        curves = [c for plots in BODE_PLOTS.values() for c in plots[0]]
        starts = ", ".join(f"{c} = {row_slice(c, n)[0]}" for c in curves)
        rows.append(f'  {{ channel = "{name}", prefix = "{node}/{token}/frequency_response/data", n = {n}, '
                    f"x = {row_slice(_X, n)[0]}, rows = {{ {starts} }} }},")
    global_code = "\n".join([
        "-- gap_validation: one XY series per channel and curve, x = log10 frequency [rad/s]",
        "-- (rows of the Float64MultiArray table: docs/NODE_TOPICS.md; indices for this config's grids)",
        "channels = {", *rows, "}",
        "series = {}",
        "for _, ch in ipairs(channels) do",
        "  series[ch.channel] = {}",
        "  for curve, _ in pairs(ch.rows) do",
        '    series[ch.channel][curve] = ScatterXY.new(ch.channel .. "/bode/" .. curve)',
        "  end",
        "end",
    ])
    function_code = "\n".join([
        "-- at the time cursor: the latest table of each channel, NaN columns left out",
        "for _, ch in ipairs(channels) do",
        "  for curve, start in pairs(ch.rows) do",
        "    local out = series[ch.channel][curve]",
        "    out:clear()",
        "    for i = 0, ch.n - 1 do",
        '      local sx = TimeseriesView.find(string.format("%s[%d]", ch.prefix, ch.x + i))',
        '      local sy = TimeseriesView.find(string.format("%s[%d]", ch.prefix, start + i))',
        "      if sx ~= nil and sy ~= nil then",
        "        local x, y = sx:atTime(tracker_time), sy:atTime(tracker_time)",
        "        if x ~= nil and y ~= nil and x == x and y == y then out:push_back(x, y) end",
        "      end",
        "    end",
        "  end",
        "end",
    ])
    return global_code, function_code


def plotjuggler_layout(config, node: str = DEFAULT_NODE) -> str:
    """The PlotJuggler (3.x) layout XML for a config's channels.

    Parameters
    ----------
    config : ValidationConfig
        The channels (names and grid sizes) to draw.
    node : str
        The node's fully qualified name.

    Returns
    -------
    str
        The layout: one tab per channel with three XY plots (magnitude, phase, coherence and epsilon), the
        reactive script that builds their series, and the ROS 2 topic subscriber's topics.
    """
    node = _node(node)
    root = ET.Element("root")
    widget = ET.SubElement(root, "tabbed_widget", {"name": "Main Window", "parent": "main_window"})
    topics = ["/diagnostics"]
    for name, token, n in plotted_channels(config):
        topics += [f"{node}/{token}/frequency_response", f"{node}/{token}/verdict"]
        tab = ET.SubElement(widget, "Tab", {"containers": "1", "tab_name": name})
        splitter = ET.SubElement(ET.SubElement(tab, "Container"), "DockSplitter", {
            "count": str(len(BODE_PLOTS)), "orientation": "-",
            "sizes": ";".join([f"{1.0 / len(BODE_PLOTS):.6f}"] * len(BODE_PLOTS))})
        for title, (curves, _) in BODE_PLOTS.items():
            area = ET.SubElement(splitter, "DockArea", {"name": f"{name}: {title}"})
            plot = ET.SubElement(area, "plot", {"mode": "XYPlot", "style": "Lines", "flip_x": "false",
                                                "flip_y": "false"})
            ET.SubElement(plot, "range", {"left": "0", "right": "2", "bottom": "0", "top": "1"})
            ET.SubElement(plot, "limitY")
            for c in curves:
                ET.SubElement(plot, "curve", {"name": f"{name}/bode/{c}", "color": _COLORS[c]})
    ET.SubElement(widget, "currentTabIndex", {"index": "0"})
    ET.SubElement(root, "use_relative_time_offset", {"enabled": "0"})
    plugins = ET.SubElement(root, "Plugins")
    streamer = ET.SubElement(plugins, "plugin", {"ID": "ROS2 Topic Subscriber"})
    ET.SubElement(streamer, "use_header_stamp", {"value": "false"})
    ET.SubElement(streamer, "discard_large_arrays", {"value": "false"})
    width = max([len(CURVES) * n for _, _, n in plotted_channels(config)] or [len(CURVES)])
    ET.SubElement(streamer, "max_array_size", {"value": str(max(width, 500))})
    ET.SubElement(streamer, "selected_topics", {"value": ";".join(topics)})
    script = ET.SubElement(plugins, "plugin", {"ID": "Reactive Script Editor"})
    ET.SubElement(script, "library", {"code": ""})
    global_code, function_code = _lua(config, node)
    scripts = ET.SubElement(script, "scripts")
    ET.SubElement(scripts, "script", {"name": "gap_validation_bode", "global": global_code,
                                      "function": function_code})
    ET.SubElement(root, "previouslyLoaded_Streamer", {"name": "ROS2 Topic Subscriber"})
    ET.SubElement(root, "customMathEquations")
    ET.SubElement(root, "snippets")
    ET.indent(root, space=" ")
    return "<?xml version='1.0' encoding='UTF-8'?>\n" + ET.tostring(root, encoding="unicode") + "\n"


def foxglove_json(config, node: str = DEFAULT_NODE) -> str:
    """:func:`foxglove_layout` as the text of a layout file.

    Parameters
    ----------
    config : ValidationConfig
        The validation config.
    node : str
        The node's fully qualified name.
    """
    return json.dumps(foxglove_layout(config, node), indent=2) + "\n"


# -- what a layout draws, evaluated on published messages (tests and the previews in docs/node.md)
# --------------

_SLICE = re.compile(r"^(?P<topic>/[^.]+)\.data\[(?P<a>\d+):(?P<b>\d+)\]$")


def _slice(path: str, messages: Mapping[str, Sequence[float]]) -> np.ndarray:
    match = _SLICE.match(path)
    if match is None:
        raise ValueError(f"not a slice of a Float64MultiArray's data: {path!r}")
    data = np.asarray(messages[match["topic"]], dtype=float)
    return data[int(match["a"]):int(match["b"]) + 1]        # message-path slices are inclusive


def foxglove_plots(layout: Mapping[str, Any], messages: Mapping[str, Sequence[float]]) -> dict[str, list]:
    """What each Plot panel of a Foxglove layout draws from the latest messages (its ``currentCustom`` x
    axis).

    Parameters
    ----------
    layout : mapping
        A layout from :func:`foxglove_layout` (or its JSON loaded).
    messages : mapping
        Topic -> the latest ``Float64MultiArray.data`` on it.

    Returns
    -------
    dict
        Panel title -> ``[(label, x, y), ...]``, NaN points left out (plotters draw them as gaps).
    """
    out = {}
    for pid, panel in layout["configById"].items():
        if not pid.startswith("Plot!"):
            continue
        x = _slice(panel["xAxisPath"]["value"], messages)
        lines = []
        for path in panel["paths"]:
            y = _slice(path["value"], messages)
            keep = np.isfinite(x) & np.isfinite(y)
            lines.append((path.get("label", path["value"]), x[keep], y[keep]))
        out[panel.get("foxglovePanelTitle", pid)] = lines
    return out


_LUA_CHANNEL = re.compile(r'\{ channel = "(?P<channel>[^"]*)", prefix = "(?P<prefix>[^"]*)", n = (?P<n>\d+), '
                          r"x = (?P<x>\d+), rows = \{ (?P<rows>[^}]*) \} \},")


def plotjuggler_series(layout_xml: str, messages: Mapping[str, Sequence[float]]) -> dict[str, tuple]:
    """The XY series the layout's reactive script builds from the latest messages.

    PlotJuggler names element ``i`` of a topic's ``data`` ``<topic>/data[i]``; the script reads, per channel
    and curve, the elements of the curve's row against those of the log10-frequency row. This follows the
    indices written into the script (its ``channels`` table), so it checks them.

    Parameters
    ----------
    layout_xml : str
        A layout from :func:`plotjuggler_layout`.
    messages : mapping
        Topic -> the latest ``Float64MultiArray.data`` on it.

    Returns
    -------
    dict
        Series name (``<channel>/bode/<curve>``) -> ``(x, y)``, NaN points left out.
    """
    root = ET.fromstring(layout_xml)
    script = root.find("./Plugins/plugin[@ID='Reactive Script Editor']/scripts/script")
    if script is None:
        raise ValueError("the layout has no reactive script")
    out = {}
    for match in _LUA_CHANNEL.finditer(script.get("global", "")):
        data = np.asarray(messages[match["prefix"].removesuffix("/data")], dtype=float)
        n, x0 = int(match["n"]), int(match["x"])
        for item in match["rows"].split(","):
            curve, start = (part.strip() for part in item.split("="))
            x, y = data[x0:x0 + n], data[int(start):int(start) + n]
            keep = np.isfinite(x) & np.isfinite(y)
            out[f"{match['channel']}/bode/{curve}"] = (x[keep], y[keep])
    return out
