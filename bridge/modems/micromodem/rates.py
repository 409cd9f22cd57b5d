"""Micro-Modem packet rates 0–5: frame size, frames per packet, nominal bit rate (pure).

Figures from the reference, section 2.2 [V]: goby ``PACKET_SIZE`` / ``PACKET_FRAME_COUNT``,
pyacomms ``Rates`` and libumutil's ``TXR_*`` names. A frame's air time is fixed: a partial frame
costs as much as a full one. Rate 6 (MM2 only) is left out: the bridge supports MM1 and MM2
rates 0–5.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["RATES", "Rate", "frame_bytes_for_rate", "get_rate"]


@dataclass(frozen=True)
class Rate:
    """One packet rate of the Micro-Modem."""

    number: int
    modulation: str
    bitrate_bps: int
    frame_bytes: int
    frames: int

    @property
    def max_bytes(self) -> int:
        """User bytes in one packet: ``frame_bytes × frames``."""
        return self.frame_bytes * self.frames

    @property
    def fsk(self) -> bool:
        """Rate 0 is FH-FSK (and is preceded by a separate cycle-init mini-packet)."""
        return self.number == 0

    def frames_for(self, n_bytes: int) -> int:
        """How many frames carry ``n_bytes`` (at least one)."""
        return max(1, -(-n_bytes // self.frame_bytes))


RATES: dict[int, Rate] = {
    r.number: r
    for r in (
        Rate(0, "FH-FSK", 80, 32, 1),
        Rate(1, "PSK BCH 128:8", 250, 64, 3),
        Rate(2, "PSK DSS 1/15", 500, 64, 3),
        Rate(3, "PSK DSS 1/7", 1200, 256, 2),
        Rate(4, "PSK BCH 64:10", 1300, 256, 2),
        Rate(5, "PSK Hamming 14:9", 5300, 256, 8),
    )
}


def get_rate(number: int) -> Rate:
    """The rate ``number`` (0–5); ``ValueError`` names the valid ones."""
    try:
        return RATES[int(number)]
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"Micro-Modem rate must be one of 0-5, got {number!r}") from None


def frame_bytes_for_rate(rate: int) -> int:
    """Largest bridge frame at ``rate``: all its WHOI frames (32, 192, 192, 512, 512, 2048 B).

    The backend splits a bridge frame over the packet's frames and the receiving backend joins
    them again, so this is the bit budget ``zab check`` should use.
    """
    return get_rate(rate).max_bytes
