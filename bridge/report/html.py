"""Draw a mission report as one self-contained HTML file (plotly, its JavaScript inline).

Plotly was chosen over matplotlib because the reader of a mission wants to zoom into a track
or a burst of losses and read exact values on hover, and plotly's HTML export embeds its one
JavaScript bundle, so the file opens offline with no server and no other file.
"""

from __future__ import annotations

import html
import math
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import plotly.graph_objects as go
from plotly.colors import qualitative
from plotly.subplots import make_subplots

from bridge.core.loaded import LoadedMission
from bridge.report.check import check_mission
from bridge.report.model import MissionReport
from bridge.report.recorder import Recording, age_series

CONFIG = {"displaylogo": False, "responsive": True}  # no link out to plotly's site
LAYOUT = {"template": "plotly_white", "margin": {"l": 60, "r": 20, "t": 50, "b": 50}}
PALETTE = qualitative.Plotly
AOI_TEETH = 1500  # per receiver line; longer runs merge teeth, keeping the tallest


def channel_bounds(loaded: LoadedMission) -> dict[str, float | None]:
    """Per channel, the age its receivers should not exceed when every send gets through
    and its sender has news: its interval, then the sender's worst wait for a transmit turn,
    then the frame's airtime (None when a sender's turns are not bounded)."""
    data = check_mission(loaded).data
    nodes = {n["name"]: n for n in data["nodes"]}
    bounds: dict[str, float | None] = {}
    for c in data["channels"]:
        waits = [nodes[s]["mac"]["worst_interval_s"] for s in c["from"] if s in nodes]
        airtimes = [nodes[s]["airtime_s"] or 0.0 for s in c["from"] if s in nodes]
        if not waits or any(w is None for w in waits):
            bounds[c["name"]] = None
            continue
        bounds[c["name"]] = round(c["interval_s"] + max(waits) + max(airtimes), 3)
    return bounds


CAPTIONS = {
    "age": "How old the latest value at each receiver is. The bound (dashed) is the "
           "channel's interval, then its sender's longest wait for a transmit turn, then the "
           "frame's airtime: what a receiver waits when every frame gets through and the "
           "sender has news. Above it: each lost frame adds a turn; a latched channel is "
           "re-sent without news, so it comes back under; one sent on news only (a command "
           "published once) ages from its last value on, by design; a vehicle reached over "
           "IP while surfaced gets no acoustic copy meanwhile.",
    "ranges": "Measured minus true distance when each range completed. A DLBL range is "
              "two-way: it averages the distance over an exchange of frames, up to a TDMA "
              "cycle apart, so where the distance changes meanwhile (a vehicle sailing away "
              "from a moored node) it reads off by up to half that change; between nodes "
              "that keep their distance the error is the ranging's own, centimetres "
              "(bench/ranging_bench.py).",
}
"""Words under a plot's heading, where the plot alone would mislead."""


def _figure_html(fig: go.Figure, name: str, first: bool, caption: str | None = None) -> str:
    fig.update_layout(**LAYOUT)
    body = fig.to_html(full_html=False, include_plotlyjs=first, config=CONFIG,
                       div_id=f"plot-{name}")
    words = f'<p class="caption">{html.escape(caption)}</p>' if caption else ""
    return f'<section class="plot" data-plot="{name}">{words}{body}</section>'


def tracks_figure(rec: Recording) -> go.Figure:
    """Truth tracks, and the bridge's fixes with their 1-sigma circles when there are any."""
    fig = go.Figure()
    names = sorted({*rec.tracks, *rec.fixes})
    colour = {n: PALETTE[i % len(PALETTE)] for i, n in enumerate(names)}
    for node, points in sorted(rec.tracks.items()):
        xs, ys = [p[1] for p in points], [p[2] for p in points]
        still = max(xs) - min(xs) < 0.5 and max(ys) - min(ys) < 0.5  # moored or static
        fig.add_trace(go.Scatter(x=xs[-1:] if still else xs, y=ys[-1:] if still else ys,
                                 mode="markers+text" if still else "lines",
                                 text=[node] if still else None, textposition="top center",
                                 marker={"size": 9, "color": colour[node]},
                                 line={"color": colour[node]},
                                 name=f"{node} truth", legendgroup=node,
                                 hovertext=[f"{node} t={p[0]:.0f} s" for p in points]))
    for node, fixes in sorted(rec.fixes.items()):
        fig.add_trace(go.Scatter(
            x=[f[1] for f in fixes], y=[f[2] for f in fixes], mode="markers",
            name=f"{node} fix", legendgroup=node,
            marker={"symbol": "cross", "size": 7, "color": colour[node]},
            error_x={"type": "data", "array": [f[3] or 0 for f in fixes], "visible": True},
            error_y={"type": "data", "array": [f[3] or 0 for f in fixes], "visible": True},
            hovertext=[f"{node} fix t={f[0]:.0f} s ±{f[3] or 0:.1f} m" for f in fixes]))
    fig.update_layout(title="Tracks: truth (lines) and fixes ±1σ (crosses)",
                      xaxis_title="x east (m)", yaxis_title="y north (m)", height=520)
    fig.update_yaxes(scaleanchor="x", scaleratio=1)
    return fig


LOSS_COLOURS = {  # one colour per cause, the same in every report
    "loss": "#7f7f7f", "bit_errors": "#bcbd22", "collision": "#d62728",
    "half_duplex": "#ff7f0e", "out_of_range": "#9467bd", "range_loss": "#1f77b4",
}


def age_title(channel: str, bound: float | None, latching: bool) -> str:
    """A subplot's title: the channel, its bound, and when the bound holds."""
    if bound is None:
        return f"{channel} (no bound: its sender's turns are not bounded)"
    if latching:
        return f"{channel}: latched, re-sent without news (bound {bound:.1f} s)"
    return f"{channel}: sent on news only (bound {bound:.1f} s while there is news)"


def age_figure(rec: Recording, bounds: dict[str, float | None],
               channels: list[str], latching: dict[str, bool] | None = None) -> go.Figure:
    """Per channel, age of information at each receiver over time, against its bound (its
    title says when the bound holds: a latched channel is re-sent without news; one sent on
    news only, a command published once, ages from its last value on)."""
    shown = [c for c in channels if any(ch == c for ch, _ in rec.arrivals)] or channels[:1]
    fig = make_subplots(rows=len(shown), cols=1, shared_xaxes=True, vertical_spacing=0.04,
                        subplot_titles=[age_title(c, bounds.get(c), (latching or {}).get(c, True))
                                        for c in shown])
    for row, channel in enumerate(shown, start=1):
        for (ch, node), arrivals in sorted(rec.arrivals.items()):
            if ch != channel:
                continue
            times, ages = age_series(arrivals, rec.end_s, AOI_TEETH)
            fig.add_trace(go.Scatter(x=times, y=ages, mode="lines",
                                     name=f"{channel} at {node}", legendgroup=channel,
                                     line={"width": 1}), row=row, col=1)
        bound = bounds.get(channel)
        if bound is not None:
            fig.add_hline(y=bound, line={"dash": "dash", "color": "firebrick"}, row=row, col=1)
        fig.update_yaxes(title_text="age (s)", row=row, col=1)
    fig.update_xaxes(title_text="time (s)", row=len(shown), col=1)
    fig.update_layout(title="Age of information per channel (dashed: bound)",
                      height=max(320, 200 * len(shown)), showlegend=True)
    if not rec.arrivals:
        fig.add_annotation(text="no channel arrived anywhere: nothing was published on the "
                           "vehicles' input keys", showarrow=False, xref="paper",
                           yref="paper", x=0.5, y=0.5, font={"size": 14})
    return fig


def slots_figure(rec: Recording, loaded: LoadedMission, turns: dict[str, float | None]) -> \
        go.Figure:
    """Per node: frames sent, stacked by the channels they carried, and the frame fill."""
    nodes = list(loaded.mission.nodes)
    carried: dict[str, Counter[str]] = defaultdict(Counter)
    fill: dict[str, list[float]] = defaultdict(list)
    for _, node, size, channels in rec.frames:
        for channel in channels or ["(empty)"]:
            carried[channel][node] += 1
        fill[node].append(size / loaded.mission.frame_bytes_of(node))  # (its smallest link)
    fig = go.Figure()
    for channel in sorted(carried):
        fig.add_trace(go.Bar(x=nodes, y=[carried[channel][n] for n in nodes], name=channel))
    sent = Counter(node for _, node, _, _ in rec.frames)
    labels = []
    for n in nodes:
        wait = turns.get(n)
        offered = math.floor(rec.end_s / wait) + 1 if wait else None
        use = f"{sent[n]} of ~{offered:.0f} turns" if offered else f"{sent[n]} frames"
        mean = sum(fill[n]) / len(fill[n]) if fill[n] else 0.0
        labels.append(f"{use}, fill {mean:.0%}")
    fig.add_trace(go.Scatter(x=nodes, y=[0] * len(nodes), mode="text", text=labels,
                             textposition="bottom center", showlegend=False, hoverinfo="skip"))
    fig.update_layout(barmode="stack", title="Slot use per node: frames sent, by channel carried",
                      yaxis_title="frames carrying the channel", height=420)
    return fig


def losses_figure(report: MissionReport) -> go.Figure:
    """Per link, frames lost in the water, stacked by why."""
    links = report.links
    names = [link.name for link in links]
    reasons = sorted({r for link in links for r, n in link.lost.items() if n})
    fig = go.Figure()
    for i, reason in enumerate(reasons):
        fig.add_trace(go.Bar(
            x=names, y=[link.lost.get(reason, 0) for link in links], name=reason.replace("_", " "),
            marker={"color": LOSS_COLOURS.get(reason, PALETTE[i % len(PALETTE)])},
            hovertext=[f"{link.name}: {link.lost.get(reason, 0)} lost ({reason}) of "
                       f"{link.sent} sent, {link.delivered} delivered" for link in links],
            hoverinfo="text"))
    fig.update_layout(barmode="stack", title="Frames lost per link, by cause",
                      yaxis_title="frames lost", height=420, showlegend=True,
                      legend_title_text="cause")
    if not reasons:
        sent = sum(link.sent for link in links)
        fig.add_annotation(text=f"no frame lost on any link ({sent} sent)", showarrow=False,
                           xref="paper", yref="paper", x=0.5, y=0.6, font={"size": 16})
        fig.update_yaxes(range=[0, 1])
    return fig


def ranges_figure(rec: Recording) -> go.Figure:
    """DLBL/TWR ranges minus the true distance, per observer → peer, over time."""
    series: dict[str, list[tuple[float, float]]] = defaultdict(list)
    for t, observer, peer, measured, truth in rec.ranges:
        if truth is not None:
            series[f"{observer}→{peer}"].append((t, measured - truth))
    worst = max((abs(e) for points in series.values() for _, e in points), default=0.0)
    unit, factor = ("mm", 1000.0) if worst < 0.1 else ("m", 1.0)
    series = {k: [(t, e * factor) for t, e in v] for k, v in series.items()}
    fig = go.Figure()
    for name, points in sorted(series.items()):
        fig.add_trace(go.Scatter(x=[p[0] for p in points], y=[p[1] for p in points],
                                 mode="markers", name=name, marker={"size": 5}))
    fig.add_hline(y=0, line={"color": "grey"})
    fig.update_layout(title="Range errors: measured − true distance when the range was "
                      "completed"
                      + ("" if series else " (no ranges measured)"),
                      xaxis_title="time (s)", yaxis_title=f"error ({unit})",
                      height=420 + 22 * ((len(series) + 5) // 6),
                      # a pair per entry: in rows under the plot, never a clipped scroll box
                      legend={"orientation": "h", "yanchor": "top", "y": -0.18,
                              "x": 0, "entrywidth": 110})
    return fig


def _summary_html(report: MissionReport, rec: Recording) -> str:
    rows = []
    for c in report.channels.values():
        rows.append(f"<tr><td>{html.escape(c.name)}</td><td>{c.bits}</td><td>{c.sent}</td>"
                    f"<td>{c.delivered}</td><td>{_s(c.age and c.age.mean_s)}</td>"
                    f"<td>{_s(c.age and c.age.max_s)}</td></tr>")
    errors = [abs(m - t) for _, _, _, m, t in rec.ranges if t is not None]
    ranges = (f"{len(errors)} ranges, median error {sorted(errors)[len(errors) // 2]:.3f} m"
              if errors else "no ranges measured")
    return ("<table><thead><tr><th>channel</th><th>bits</th><th>sent in frames</th>"
            "<th>received</th><th>mean age</th><th>max age</th></tr></thead><tbody>"
            + "".join(rows)
            + f"</tbody></table><p>{report.frames_sent} frames sent; {html.escape(ranges)}. "
            "“Sent in frames” counts values a bridge carried, the newest at each turn (values "
            "superseded before their turn are not lost: receivers keep the latest value); "
            "“received” counts arrivals at all receivers together.</p>")


def _s(v: Any) -> str:
    return "—" if not isinstance(v, int | float) or not math.isfinite(v) else f"{v:.1f} s"


def write_report(path: Path, report: MissionReport, rec: Recording,
                 loaded: LoadedMission) -> Path:
    """Write the report page to ``path`` and return it."""
    bounds = channel_bounds(loaded)
    turns = {n["name"]: n["mac"]["worst_interval_s"]
             for n in check_mission(loaded).data["nodes"]}
    channels = [c.name for c in loaded.table.channels]
    latching = {c.name: c.latching for c in loaded.table.channels}
    figures = [("tracks", tracks_figure(rec)),
               ("age", age_figure(rec, bounds, channels, latching)),
               ("slots", slots_figure(rec, loaded, turns)), ("losses", losses_figure(report)),
               ("ranges", ranges_figure(rec))]
    plots = "\n".join(_figure_html(fig, name, i == 0, CAPTIONS.get(name))
                      for i, (name, fig) in enumerate(figures))
    title = f"zab mission report: {report.mission}"
    clock = "virtual clock" if report.clock == "virtual" else "real time"
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<meta name="viewport" content="width=device-width, initial-scale=1">
<style>
body {{ font-family: system-ui, sans-serif; margin: 1.5rem auto; max-width: 1100px;
       padding: 0 1rem; color: #1b2631; }}
table {{ border-collapse: collapse; margin: 0.5rem 0; }}
td, th {{ padding: 0.2rem 0.8rem 0.2rem 0; text-align: left; border-bottom: 1px solid #ddd; }}
section.plot {{ margin: 1.5rem 0; }}
p.caption {{ color: #4d5b69; margin: 0.2rem 0; }}
</style></head><body>
<h1>{html.escape(title)}</h1>
<p>{report.duration_s:.0f} s simulated ({clock}), {len(loaded.mission.nodes)} nodes,
{len(channels)} channels. Everything below is drawn from this one file; it needs no network.</p>
{_summary_html(report, rec)}
{plots}
</body></html>
"""
    path.write_text(page, encoding="utf-8")
    return path
