"""Turn a node of the mission into a modem backend (setup + factory)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from bridge.mission.model import Mission
from bridge.mission.network import Network
from bridge.modems.base import ModemBackend, ModemSetup
from bridge.modems.registry import load_backend


def modem_options(mission: Mission, node: str) -> dict[str, Any]:
    """The options a backend of ``node`` reads: the merged ``options``, with ``broadcast``
    from the mission's modem settings when it gives one."""
    modem = mission.node_modem(node)
    broadcast = {} if modem.broadcast is None else {"broadcast": modem.broadcast}
    return {**modem.options, **broadcast}


def modem_setup(mission: Mission, node: str, extra: Mapping[str, Any] | None = None) -> ModemSetup:
    """The :class:`ModemSetup` of ``node``: merged options, peers' options, static position."""
    modem = mission.node_modem(node)
    position = mission.nodes[node].position
    return ModemSetup(
        node=node,
        address=mission.nodes[node].address,
        frame_bytes=modem.frame_bytes,
        options={**modem_options(mission, node), **(extra or {})},
        peers={
            other.address: {**modem_options(mission, name), **(extra or {})}
            for name, other in mission.nodes.items()
            if name != node
        },
        position=(position.x, position.y, position.depth) if position else None,
    )


def backend_factory(
    mission: Mission, node: str, extra: Mapping[str, Any] | None = None
) -> Callable[[], ModemBackend]:
    """A function that makes a fresh backend for ``node`` (the runtime reopens with it)."""
    cls = load_backend(mission.node_modem(node).backend)
    setup = modem_setup(mission, node, extra)
    return lambda: cls(setup)


def node_backends(network: Network, node: str,
                  extras: Mapping[str | None, Mapping[str, Any]] | None = None,
                  ) -> Callable[[], ModemBackend] | dict[str, Callable[[], ModemBackend]]:
    """What makes ``node``'s modem backend, or with several links each link's, by name
    (``extras``: more options per link name; None: the mission's one link)."""
    extras = extras or {}
    if not network.several:
        return backend_factory(network.mission, node, extras.get(None))
    return {link.name: backend_factory(link.view, node, extras.get(link.name))
            for link in network.links_of(node)}
