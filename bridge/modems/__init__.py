"""Modem backends: one async interface over simulated, UDP and real acoustic modems."""

from bridge.modems.base import ModemBackend, ModemSetup, Reception
from bridge.modems.registry import available_backends, load_backend

__all__ = ["ModemBackend", "ModemSetup", "Reception", "available_backends", "load_backend"]
