"""Fusion server: ZeroMQ ingest, time alignment, fusion, tracking, WebSocket and REST out."""
