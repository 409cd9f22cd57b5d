"""The ids a sender gives its values: each used once, across restarts too (pure).

An accepted value changes what a restart must resume (its queue), so the state is saved
before it is reported, and its id with it. A refused value (its queue full, or the state not
savable) changes nothing else, so its id must not cost a save of its own: an application
flooding a full reliable channel made a node save its whole state once per refused put, and
its event loop, busy saving, sent nothing else (2 of 50 navigation values crossed in 50 s).
Refusals draw on a block of ids reserved in the saved state instead: a save is needed only
when a refusal takes the first id of a new block, and a restart resumes past the block, so no
id reported before a crash is reported again for another value.
"""

from __future__ import annotations

__all__ = ["BLOCK", "Ids"]

BLOCK = 1024
"""Ids reserved at a time for refusals (a save each ``BLOCK`` refusals, at most)."""


class Ids:
    """One sender's value ids."""

    __slots__ = ("next", "reserved")

    def __init__(self, start: int = 0) -> None:
        self.next = start
        self.reserved = start
        """Ids below this may be handed out without a save: the saved state resumes here."""

    def take(self) -> int:
        """The id of an accepted value (the state is saved before it is reported)."""
        taken = self.next
        self.next += 1
        return taken

    def take_refused(self) -> tuple[int, bool]:
        """The id of a refused value, and whether the state must be saved for it (its id
        starts a new reserved block)."""
        taken = self.take()
        if self.next <= self.reserved:
            return taken, False
        self.reserved = self.next + BLOCK
        return taken, True

    def state(self) -> int:
        """Where a restart resumes: past every id handed out or reserved."""
        return max(self.next, self.reserved)

    @classmethod
    def restore(cls, state: int) -> Ids:
        return cls(int(state))
