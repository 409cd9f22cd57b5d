"""``python -m bridge`` runs the ``zab`` command line."""

from bridge.cli import main

main()
