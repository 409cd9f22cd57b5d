"""Runtimes around the core: the Zenoh node, the in-process fleet, the virtual-clock fleet."""
