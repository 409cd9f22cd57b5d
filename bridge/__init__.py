"""zenoh-acoustic-bridge."""
