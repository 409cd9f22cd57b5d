"""The bridge logic of one node, sans I/O: store, frame building, MAC, reliability, ranging.

Nothing here imports asyncio, Zenoh, serial or aiohttp; every method takes the time it needs.
"""
