"""Fusion server: ZeroMQ ingest, time alignment, fusion, tracking, WebSocket and REST out."""

__version__ = "0.1.0"
