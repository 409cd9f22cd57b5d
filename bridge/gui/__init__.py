"""``zab gui``: the surface GUI in the browser.

:mod:`~bridge.gui.model` (with :mod:`~bridge.gui.keys`, :mod:`~bridge.gui.commands` and
:mod:`~bridge.gui.eventlog`) is the pure picture of the fleet; :mod:`~bridge.gui.feed` is the
Zenoh adapter and :mod:`~bridge.gui.server` the aiohttp web server; the page is plain
HTML/JS/CSS under ``static/``.
"""
