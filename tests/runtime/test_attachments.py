"""The attachment a bridge publishes (issue 32): its marker, the application's bytes after a
NUL where a channel carries them, and the signature (wire.auth.sign_outputs) over both."""

from __future__ import annotations

from bridge.runtime.session import bridged_attachment, marked, origin_of
from bridge.wire.proofs import check_output, sign_output

KEY = b"k" * 32
MARKER = b"zab/1 m/top"


def test_the_applications_attachment_rides_behind_the_marker_under_the_signature() -> None:
    assert marked(MARKER, None) == MARKER and marked(MARKER, b"") == MARKER
    carried = marked(MARKER, b"trip sig=7")  # whatever bytes the application used
    assert carried == MARKER + b"\x00trip sig=7" and bridged_attachment(carried)
    signed = sign_output(KEY, carried, "auv1/status", 5, b"payload")
    assert origin_of(signed) == origin_of(carried) == origin_of(MARKER) == MARKER
    assert check_output(KEY, "auv1/status", b"payload", signed) == (
        "zab/1 m/top\x00trip sig=7", 5)
    altered = signed.replace(b"trip", b"trap")
    assert check_output(KEY, "auv1/status", b"payload", altered) is None
