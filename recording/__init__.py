"""Recordings of agents' raw streams, offline replay through the fusion layer, and exports.

The file format itself is a contract, in :mod:`skelfuse.protocol.recording_file` (an agent reads
recordings through it). ``recording.recorder`` needs only numpy and msgpack; ``recording.replay``
runs the fusion layer, so it needs the server extra.
"""
