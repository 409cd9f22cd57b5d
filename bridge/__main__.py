"""``python -m bridge`` runs the ``zab`` command line."""

from bridge.cli.app import main

main()
