"""Proofs with the mission key on the Zenoh side (pure): a peer bridge reachable over IP, and
what a bridge publishes.

Anything on a vehicle's Zenoh network can declare a liveliness token or put a sample on any
key, so a bridge believes neither a token nor an attachment alone:

- **Surfacing** (:func:`surfacing_proof`). A bridge that sees a peer's token
  ``@zab/<mission>/<peer>/bridge`` asks the peer's queryable ``@zab/<mission>/<peer>/prove``
  with a fresh random nonce; the peer answers with a keyed hash of the mission, both names and
  the nonce. The answer proves that a holder of the key answers over that path now: a local
  application declaring the token cannot, and a recorded answer fits no other nonce.
- **Outputs** (:func:`sign_output`, :func:`check_output`). Where the mission asks
  (``wire.auth.sign_outputs``), every sample a bridge puts (decoded values, delivery reports,
  status, events, relays, latched answers) carries after its origin tag ``sig=<counter>.<tag>``:
  a keyed hash of the origin, the key expression, the counter and the payload. An application
  holding the key checks it with :func:`check_output` (or its few lines in any language:
  docs/developers.md) and keeps the last counter per origin and key to refuse a replay.

The hash is HMAC-SHA256 with the mission key, each with its own label, so a proof of one kind
is never valid as another (nor as a frame's tag).
"""

from __future__ import annotations

import hashlib
import hmac

SURFACING_LABEL = b"zab-surface/1\0"
OUTPUT_LABEL = b"zab-out/1\0"
OUTPUT_TAG_BYTES = 16
SIGNATURE = b" sig="


def surfacing_proof(key: bytes, mission: str, prover: str, asker: str, nonce: str) -> str:
    """What ``prover``'s bridge answers ``asker``'s challenge ``nonce`` with (hex)."""
    text = "\0".join((mission, prover, asker, nonce)).encode()
    return hmac.new(key, SURFACING_LABEL + text, hashlib.sha256).hexdigest()


def proven(key: bytes, mission: str, prover: str, asker: str, nonce: str, answer: object
           ) -> bool:
    """Whether ``answer`` is ``prover``'s proof for ``asker``'s ``nonce``."""
    return isinstance(answer, str) and hmac.compare_digest(
        answer, surfacing_proof(key, mission, prover, asker, nonce))


def _output_tag(key: bytes, origin: bytes, key_expr: str, counter: int, payload: bytes) -> str:
    text = origin + b"\0" + key_expr.encode() + b"\0" + counter.to_bytes(8, "big") + payload
    return hmac.new(key, OUTPUT_LABEL + text, hashlib.sha256).hexdigest()[:2 * OUTPUT_TAG_BYTES]


def sign_output(key: bytes, origin: bytes, key_expr: str, counter: int, payload: bytes
                ) -> bytes:
    """The attachment of a signed sample: ``origin`` (the bridge's ``zab/1 <mission>/<node>``
    tag), then `` sig=<counter>.<tag>``."""
    tag = _output_tag(key, origin, key_expr, counter, payload)
    return origin + SIGNATURE + f"{counter}.{tag}".encode()


def check_output(key: bytes, key_expr: str, payload: bytes, attachment: bytes | None
                 ) -> tuple[str, int] | None:
    """``(origin, counter)`` if a holder of ``key`` signed this sample (its key expression,
    payload and attachment); None if it is unsigned, altered or forged."""
    if not attachment or SIGNATURE not in attachment:
        return None
    origin, _, signature = attachment.rpartition(SIGNATURE)
    counter_text, _, tag = signature.partition(b".")
    try:
        counter = int(counter_text)
    except ValueError:
        return None
    if not 0 <= counter < 1 << 64:
        return None
    expected = _output_tag(key, origin, key_expr, counter, payload).encode()
    if not hmac.compare_digest(tag, expected):
        return None
    return origin.decode("utf-8", "replace"), counter
