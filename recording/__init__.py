"""Recordings of agents' raw streams, offline replay through the fusion server, and exports.

``recording.format`` and ``recording.recorder`` need only numpy and msgpack (an agent can read a
recording); ``recording.replay`` runs the server's fusion, so it needs the server extra.
"""
