"""Emulated modems for tests and demos: the host protocol on a pty (or TCP), frames in the
simulated water. :class:`~bridge.emulators.pty_host.PtyHost` is the shared pseudo-terminal side."""

from bridge.emulators.pty_host import PtyHost, TcpHost

__all__ = ["PtyHost", "TcpHost"]
