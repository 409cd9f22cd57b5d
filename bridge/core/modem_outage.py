"""A modem's outages, as its runtime opens it again and again (pure, time an argument).

The runtime retries a modem that fails or cannot be opened, with backoff. Operators hear of
each outage once: a :class:`~bridge.core.events.ModemDown` at its first failure, and a
:class:`~bridge.core.events.ModemUp` when the modem is ready again, saying how long it was
down and how many retries failed meanwhile.
"""

from __future__ import annotations

from bridge.core.events import ModemDown, ModemUp

__all__ = ["ModemOutage"]


class ModemOutage:
    """The outage under way of one modem, if any."""

    def __init__(self) -> None:
        self.since: float | None = None
        """When the outage under way began (None: the modem is up, or not opened yet)."""
        self.retries = 0
        """The tries that failed since it began, the first one not counted."""

    def failed(self, error: str, now: float) -> ModemDown | None:
        """The modem failed or could not be opened: the outage's event, if it begins now."""
        if self.since is not None:
            self.retries += 1
            return None
        self.since, self.retries = now, 0
        return ModemDown(now, error)

    def opened(self, now: float) -> ModemUp | None:
        """The modem is ready: the end of the outage under way, if one was."""
        if self.since is None:
            return None
        up = ModemUp(now, now - self.since, self.retries)
        self.since = None
        return up
