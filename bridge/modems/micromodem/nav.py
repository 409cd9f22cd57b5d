"""LBL navigation pings of the Micro-Modem: ``$CCPDT``, ``$CCPNT`` and their ``$SNTTA`` (pure).

The modem interrogates up to four long-baseline transponders, A to D, and after a listening
window prints their one-way travel times in one ``$SNTTA`` (reference 2.3 [V]):

* ``$CCPDT,group,channel,sf,sto,timeout_ms,af,bf,cf,df``: REMUS digital transponders, group 1,
  interrogation channel 1-4; ``af``..``df`` 1 for each transponder listened for (goby
  ``ccpdt``, libumutil ``MSG_CCPDT`` [V]; ``sf``/``sto`` synchronise to a PPS, which goby and
  this driver leave 0). The modem echoes it as ``$SNPDT`` with the same nine fields (pyacomms'
  ``SNPDT`` reads nine [V]; it names fields 3-4 band and gain, the values are echoed as sent).
* ``$CCPNT,ftx_hz,ttx_ms,trx_ms,timeout_ms,fa,fb,fc,fd,tflag``: narrowband transponders
  interrogated at ``ftx_hz``, each answering at its own frequency (0: not listened for);
  ``tflag`` 1 transmits the interrogation, 0 takes its timing from an external pulse (goby's
  ``transmit_flag`` [V]). The echo ``$SNPNT`` starts with the time ``hhmmss`` (libumutil's
  ``MSG_SNPNT``, ten integers [C: its comment names eleven]).
* ``$SNTTA,ta,tb,tc,td,hhmmss.ss``: one-way travel times in seconds, empty for a transponder
  not heard (pyacomms reads an empty field [V]), and the time of the interrogation.

The listening window (``timeout_ms``) is what goby gives: twice the longest range over a
rough 1500 m/s, plus the transponders' turn-around (``TAT``, 50 ms for REMUS) [V goby].
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from typing import Any

from bridge.modems.micromodem.nmea import Sentence

__all__ = ["BEACONS", "Interrogation", "Transponders", "TravelTimes", "interrogation",
           "narrowband", "remus", "travel_times", "tta", "window_ms"]

BEACONS = "ABCD"
"""The transponders one interrogation listens for, in ``$SNTTA``'s order."""

ROUGH_SOUND_SPEED = 1500.0
"""What goby divides the longest range by for the listening window [V]."""


@dataclasses.dataclass(frozen=True)
class Interrogation:
    """One LBL ping as the modem takes it: which transponders it listens for, for how long,
    whether it transmits, and its echo's fields."""

    kind: str  # "PDT" (REMUS digital) or "PNT" (narrowband)
    listen: tuple[bool, ...]
    window_s: float
    transmit: bool
    fields: tuple[int, ...]


@dataclasses.dataclass(frozen=True)
class TravelTimes:
    """``$SNTTA``: the one-way travel time to each of the transponders A-D (None: not heard)
    and the modem's ``hhmmss.ss`` of the interrogation."""

    times: tuple[float | None, ...]
    time: str

    def heard(self) -> dict[str, float]:
        """The travel time of each transponder heard, by letter."""
        return {b: t for b, t in zip(BEACONS, self.times, strict=True) if t is not None}


def window_ms(max_range_m: float, turnaround_ms: int) -> int:
    """goby's listening window: there and back at the longest range, plus the turn-around."""
    return int(max_range_m * 2.0 / ROUGH_SOUND_SPEED * 1000 + turnaround_ms)


def _letters(letters: Iterable[str]) -> set[str]:
    chosen = {str(b).upper() for b in letters}
    if not chosen or not chosen <= set(BEACONS):
        raise ValueError(f"transponders are letters of {BEACONS}, got {sorted(chosen)}")
    return chosen


def remus(channel: int, timeout_ms: int, beacons: set[str]) -> Sentence:
    """``$CCPDT`` interrogating REMUS digital transponders on ``channel`` (1-4)."""
    if not 1 <= channel <= 4 or timeout_ms <= 0:
        raise ValueError(f"channel must be 1-4 and the window positive (got {channel}, "
                         f"{timeout_ms} ms)")
    chosen = _letters(beacons)
    flags = [str(int(b in chosen)) for b in BEACONS]
    return Sentence("CC", "PDT", ("1", str(channel), "0", "0", str(timeout_ms), *flags))


def narrowband(tx_hz: int, ping_ms: int, timeout_ms: int, reply_hz: Mapping[str, int],
               reply_ms: int | None = None) -> Sentence:
    """``$CCPNT`` interrogating narrowband transponders at ``tx_hz``, each answering at its
    ``reply_hz``; the modem transmits the interrogation (``tflag`` 1)."""
    chosen = _letters(reply_hz)
    if tx_hz <= 0 or ping_ms <= 0 or timeout_ms <= 0 or any(
            int(reply_hz[b]) <= 0 for b in reply_hz):
        raise ValueError("frequencies, ping length and window must be positive")
    freqs = [str(int(reply_hz.get(b, 0))) if b in chosen else "0" for b in BEACONS]
    return Sentence("CC", "PNT", (str(tx_hz), str(ping_ms), str(reply_ms or ping_ms),
                                  str(timeout_ms), *freqs, "1"))


def interrogation(s: Sentence) -> Interrogation:
    """The ping a host's ``$CCPDT``/``$CCPNT`` asks for; ``ValueError`` if malformed."""
    if len(s.fields) != 9:
        raise ValueError(f"${s.name} takes 9 fields, got {len(s.fields)}")
    f = tuple(int(x) for x in s.fields)
    if s.kind == "PDT":
        group, channel, _sf, _sto, timeout, *flags = f
        if group != 1 or not 1 <= channel <= 4 or any(x not in (0, 1) for x in flags):
            raise ValueError("group 1, channel 1-4, flags 0 or 1")
        listen, transmit = tuple(x == 1 for x in flags), True
    elif s.kind == "PNT":
        ftx, ttx, trx, timeout, *freqs, tflag = f
        if ftx <= 0 or ttx <= 0 or trx <= 0 or tflag not in (0, 1) or min(freqs) < 0:
            raise ValueError("positive frequency and lengths, tflag 0 or 1")
        listen, transmit = tuple(x > 0 for x in freqs), tflag == 1
    else:
        raise ValueError(f"${s.name} is no LBL ping")
    if timeout <= 0:
        raise ValueError("the listening window must be positive")
    return Interrogation(s.kind, listen, timeout / 1000, transmit, f)


def travel_times(fields: tuple[str, ...]) -> TravelTimes:
    """``$SNTTA``'s fields; ``ValueError`` if malformed."""
    if len(fields) != 5:
        raise ValueError(f"$SNTTA has 5 fields, got {len(fields)}")
    times = tuple(float(x) if x else None for x in fields[:4])
    if any(t is not None and not 0.0 <= t < 100.0 for t in times):
        raise ValueError("travel time out of range")
    float(fields[4])
    return TravelTimes(times, fields[4])


def tta(times: Mapping[str, float], at: float) -> Sentence:
    """``$SNTTA`` for the transponders heard (``times`` by letter) of a ping at ``at`` (seconds
    of the day on the modem clock)."""
    cs = int(at % 86400 * 100)  # hundredths of a second of the day
    hhmmss = f"{cs // 360000:02d}{cs // 6000 % 60:02d}{cs % 6000 // 100:02d}.{cs % 100:02d}"
    return Sentence("SN", "TTA", (*(f"{times[b]:.4f}" if b in times else "" for b in BEACONS),
                                  hhmmss))


@dataclasses.dataclass(frozen=True)
class Transponders:
    """The LBL transponders a node ranges to, from its driver's ``lbl`` option::

        lbl: {beacons: {A: 11, B: 12}, max_range_m: 2000}          # REMUS digital, channel 1
        lbl: {beacons: {A: 11}, kind: narrowband, tx_hz: 9000,
              reply_hz: {A: 10000}, ping_ms: 10, max_range_m: 2000}

    ``beacons`` maps each transponder's letter to the mission node (address) it stands for.
    One interrogation listens for all of them.
    """

    by_address: Mapping[int, str]
    sentence: Sentence
    window_s: float

    @classmethod
    def from_option(cls, option: Mapping[str, Any]) -> Transponders:
        """``ValueError`` names what is wrong."""
        known = {"beacons", "kind", "channel", "tx_hz", "reply_hz", "ping_ms", "max_range_m",
                 "turnaround_ms"}
        if unknown := set(option) - known:
            raise ValueError(f"lbl: unknown keys {sorted(unknown)} (known: {sorted(known)})")
        beacons = {str(k).upper(): int(v) for k, v in dict(option.get("beacons") or {}).items()}
        _letters(beacons)
        if len(set(beacons.values())) != len(beacons):
            raise ValueError("lbl: two beacons stand for one address")
        window = window_ms(float(option.get("max_range_m", 2000.0)),
                           int(option.get("turnaround_ms", 50)))
        kind = str(option.get("kind", "remus"))
        if kind == "remus":
            sentence = remus(int(option.get("channel", 1)), window, set(beacons))
        elif kind == "narrowband":
            reply = {str(k).upper(): int(v) for k, v in dict(option.get("reply_hz") or {}).items()}
            if set(reply) != set(beacons):
                raise ValueError("lbl: narrowband needs a reply_hz for every beacon")
            sentence = narrowband(int(option.get("tx_hz", 0)), int(option.get("ping_ms", 10)),
                                  window, reply)
        else:
            raise ValueError(f"lbl: kind is remus or narrowband, not {kind!r}")
        return cls({a: b for b, a in beacons.items()}, sentence, window / 1000)
