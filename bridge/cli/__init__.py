"""The ``zab`` command line: :mod:`.app` declares the commands, one module per larger command."""

from bridge.cli.app import main

__all__ = ["main"]
