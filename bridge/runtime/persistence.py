"""Saving a node's state as it changes, and going on when the disk cannot take it.

The runtime saves the core's state (:meth:`~bridge.core.node.NodeCore.state`) before it carries
out what depends on it. A save can fail mid-mission: the state directory's filesystem full
(``ENOSPC``) or remounted read-only (``EROFS``). Such a failure never escapes into the thread
that asked (a modem's reader, the event loop's timers): :meth:`Persistence.save` reports it
once (a log line; the core's :meth:`~bridge.core.node.NodeCore.storage` makes it an event, a
status and stats), then tries again at most every :data:`RETRY_S` while the state keeps
changing, and says so once when a save works again. Meanwhile the node goes on: latest-value
channels keep crossing, and the core refuses new reliable values with the reason (see
:class:`~bridge.core.saving.Saving`).

At start the first save is a check: a state directory that cannot take it stops the node with
one line (:class:`~bridge.runtime.state_file.StateError`) before anything is sent.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import Any

from bridge.runtime.state_file import StateError, StateFile

log = logging.getLogger("zab.state")

RETRY_S = 1.0
"""Least time between two attempts while saves fail (each costs a temporary file)."""


def problem(error: OSError) -> str:
    """An OSError as a short reason: ``No space left on device (ENOSPC)``."""
    import errno  # (only on a failure)

    name = errno.errorcode.get(error.errno or 0)
    text = error.strerror or str(error)
    return f"{text} ({name})" if name else text


class Persistence:
    """The saves of one node's state file (None: nothing is saved, every save succeeds)."""

    def __init__(self, state_file: StateFile | None, node: str) -> None:
        self.state_file = state_file
        self.node = node
        self.error: str | None = None
        """Why the last save failed; None while saves work."""
        self.failed = 0
        """Saves that failed, since the start."""
        self._tried = -math.inf

    def save(self, state: Callable[[], dict[str, Any]], now: float, *,
             first: bool = False) -> bool | None:
        """Save ``state()``; True if it is saved, False if not (yet). None: not tried now
        (saves are failing and the last attempt is less than :data:`RETRY_S` old).

        ``first``: the save at start, where a failure is a :class:`StateError`."""
        if self.state_file is None:
            return True
        if self.error is not None and not first and now - self._tried < RETRY_S:
            return None
        self._tried = now
        try:
            self.state_file.save(state())
        except OSError as exc:
            reason = problem(exc)
            if first:
                raise StateError(f"{self.node}: cannot save its state in "
                                 f"{self.state_file.path.parent}: {reason}") from None
            self.failed += 1
            if self.error != reason:
                log.error("%s: cannot save its state to %s: %s (retried every %.0f s; latest-"
                          "value channels keep crossing, new reliable values are refused)",
                          self.node, self.state_file.path, reason, RETRY_S)
            self.error = reason
            return False
        if self.error is not None:
            log.warning("%s: its state is saved again to %s (%d saves had failed)", self.node,
                        self.state_file.path, self.failed)
            self.error = None
        return True

    def snapshot(self) -> dict[str, Any]:
        """For the node's stats."""
        return {"path": None if self.state_file is None else str(self.state_file.path),
                "saved": self.error is None, "error": self.error, "failed_saves": self.failed}
