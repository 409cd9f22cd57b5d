"""Whether the runtime can save the node's state, and what the node does while it cannot
(pure).

The runtime saves :meth:`~bridge.core.node.NodeCore.state` before it carries out what depends
on it; when a save fails (a full or read-only disk) it tells the core
(:meth:`~bridge.core.node.NodeCore.storage`) and keeps retrying. Meanwhile:

- latest-value channels keep crossing both ways: a restart loses nothing of theirs;
- a *new* reliable value is refused at once, reported ``failed`` with the reason: the bridge
  takes a reliable value only when a restart could not lose it without a report;
- reliable values taken before go on, and what arrives is delivered: a restart before the
  disk recovers resumes from the last state saved (values sent again, a delivered window
  behind: at least once instead of exactly once, for that window only);
- frame counters go on past the saved reservation: after such a restart peers refuse the
  reused counters as replays and say where to resume (``@mark``, docs/wire-format.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from bridge.core.events import StateSaving


@dataclass
class Saving:
    """The state of the node's saves: ``error`` is why they fail (None: they work)."""

    error: str | None = None
    since: float | None = None  # when they started failing

    def changed(self, error: str | None, now: float) -> StateSaving | None:
        """The runtime's last save ended with ``error`` (None: saved); the event, if news."""
        if error == self.error:
            return None
        since = self.since if self.since is not None else now
        self.error, self.since = error, (since if error is not None else None)
        return StateSaving(now, error, since)

    def refusal(self) -> str | None:
        """Why a new reliable value is refused now, or None."""
        if self.error is None:
            return None
        return f"not taken: the bridge cannot save its state ({self.error})"

    def snapshot(self) -> dict[str, Any]:
        return {"saved": self.error is None, "error": self.error, "since": self.since}
