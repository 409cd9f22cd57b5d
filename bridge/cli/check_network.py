"""``zab check``'s tables for a mission with several links or routes: its links, the routes
and their worst-case times, each relay's budget, and each channel's end-to-end age bound."""

from __future__ import annotations

from typing import Any

from rich.console import Console
from rich.table import Table
from rich.text import Text


def print_network(console: Console, network: dict[str, Any]) -> None:
    """The ``network`` section of ``zab check --json``, as tables."""
    links = Table("link", "kind", "mac", "members", "frame", title="links")
    for link in network["links"]:
        sizes = sorted(set(link["frame_bytes"].values()))
        links.add_row(link["name"], link["kind"], link["mac"], ", ".join(link["members"]),
                      " / ".join(f"{n} B" for n in sizes))
    console.print(links)
    if network["routes"]:
        routes = Table("from", "to", "route", "worst case", "else (a hop down)",
                       title=f"routes (max_hops "
                       f"{network['max_hops']}; network header {network['header_bytes']['plain']}"
                       f" B, {network['header_bytes']['routed']} B relayed)")
        for route in network["routes"]:
            others = "\n".join(f"{' -> '.join(o['path'])} {_seconds(o['bound_s'])}"
                               for o in route["alternatives"])
            routes.add_row(route["from"], route["to"], " -> ".join(route["path"]),
                           _seconds(route["bound_s"]), others or "-")
        console.print(routes)
    if network["relays"]:
        relays = Table("relay", "link", "own", "carried", "frames carried", "its turns carry",
                       "margin", "fits",
                       title="relay budgets (bytes per second: whole frames, acknowledgements "
                       "and headers; several carried frames share a turn)")
        for relay in network["relays"]:
            relays.add_row(relay["node"], relay["link"], f"{relay['own_Bps']:g}",
                           f"{relay['carried_Bps']:g}", f"{relay['carried_fps']:g}/s",
                           f"{relay['capacity_Bps']:g} ({relay['turns_per_s']:g} turns/s)",
                           f"{relay['margin_Bps']:g}",
                           "yes" if relay["fits"] else Text("no", style="red"))
        console.print(relays)
    ages = Table("channel", "worst from", "to", "route", "age bound",
                 title="end-to-end age (worst case across the route)")
    for age in network["age_bounds"]:
        ages.add_row(age["channel"], age["from"], age["to"], " -> ".join(age["route"]),
                     _seconds(age["age_bound_s"]))
    console.print(ages)


def _seconds(value: float | None) -> str:
    return "unbounded" if value is None else f"≤ {value:g} s"
