"""Capture agent: reads one sensor and streams its bodies to the fusion server.

Installs with numpy, pyzmq and msgpack only (no server dependencies); sensor SDKs are imported
lazily by their sources.
"""
