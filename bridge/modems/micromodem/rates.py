"""Micro-Modem packet rates 0–6: frame size, frames per packet, nominal bit rate (pure).

Figures from the reference, section 2.2 [V]: goby ``PACKET_SIZE`` / ``PACKET_FRAME_COUNT``,
pyacomms ``Rates`` (which also lists rate 6, MM2's DSS 1/15 with 32-byte frames) and
libumutil's ``TXR_*`` names. Rate 6's bit rate is not in a stored source: it takes rate 2's
500 bit/s, the same DSS 1/15 spreading [C]. A frame's air time is fixed: a partial frame
costs as much as a full one.

MM2's flexible data protocol (FDP, ``$CCTDP``) carries the data of one packet in the same
frames: pyacomms' ``FDPDataRates`` gives 3×64, 2×256 and 8×256 bytes at rates 1, 3 and 5
[V], the legacy table's figures; rates 2, 4 and 6 take theirs likewise [C]. An FDP packet sent
by ``$CCTFP`` may also carry user mini-frames, at rates 1, 3 and 5 one frame of up to 90 bytes
(pyacomms 3.1.1 ``FDPMiniRates`` [V]; the reference's 64/60/55 B came from another version).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["FDP_MINI_BYTES", "FDP_RATES", "RATES", "Rate", "frame_bytes_for_rate", "get_rate"]


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
        Rate(6, "PSK DSS 1/15 (32 B frames)", 500, 32, 6),
    )
}

FDP_RATES = frozenset(n for n in RATES if n > 0)
"""Rates an FDP packet (``$CCTDP``) may use: the PSK ones (rate 0 is FH-FSK)."""

FDP_MINI_BYTES = {1: 90, 3: 90, 5: 90}
"""User bytes an FDP packet's mini-frame carries, by its rate (one mini-frame per packet)."""


def get_rate(number: int) -> Rate:
    """The rate ``number`` (0–6); ``ValueError`` names the valid ones."""
    try:
        return RATES[int(number)]
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"Micro-Modem rate must be one of 0-6, got {number!r}") from None


def frame_bytes_for_rate(rate: int) -> int:
    """Largest bridge frame at ``rate``: all its WHOI frames (32, 192, 192, 512, 512, 2048, 192 B).

    The backend splits a bridge frame over the packet's frames and the receiving backend joins
    them again, so this is the bit budget ``zab check`` should use.
    """
    return get_rate(rate).max_bytes
