"""Plain-data helpers for the state a node saves across restarts (pure).

The core's ``state()`` methods return msgpack-able data; packed values can exceed 64 bits, so
they are kept as big-endian bytes.
"""

from __future__ import annotations


def int_to_state(value: int) -> bytes:
    """A non-negative integer of any size as bytes."""
    return value.to_bytes(max(1, (value.bit_length() + 7) // 8), "big")


def int_from_state(data: bytes | int) -> int:
    """The integer back from :func:`int_to_state` (a plain int passes through)."""
    return data if isinstance(data, int) else int.from_bytes(data, "big")
