"""Modem backends: one async interface over simulated, UDP and real acoustic modems.

:mod:`.base` (the interface, asyncio), :mod:`.registry` (backends by name), :mod:`.reception`
(what a modem hands over, pure), :mod:`.presets` (modem performance models, pure), one folder
per vendor (:mod:`.evologics`, :mod:`.micromodem`: protocol, driver and emulator side by side),
:mod:`.udp`, :mod:`.sim`. Importing this package loads nothing else.
"""
