"""skelfuse.client: read a skelfuse server's live feed from Python (``pip install
skelfuse[client]``: numpy, msgpack and websockets, none of the server's libraries).

- :class:`FeedClient` (async) and :class:`SyncFeedClient` (blocking) yield typed
  :class:`Frame` objects, reconnect with backoff and take the server's token;
- ``rotations=True`` adds each person's joint rotations (:class:`Rotations`), ``raw=True``
  every sensor's own bodies.

docs/api.md describes the feed and has a runnable example.
"""

from __future__ import annotations

from skelfuse.client.connection import (
    Backoff,
    FeedError,
    FeedRefused,
    FeedUnavailable,
    feed_url,
)
from skelfuse.client.feed import FeedClient
from skelfuse.client.frames import (
    Frame,
    Hands,
    HandState,
    Person,
    RawBody,
    Rotations,
    Skeleton,
)
from skelfuse.client.sync import SyncFeedClient

__all__ = [
    "Backoff",
    "FeedClient",
    "FeedError",
    "FeedRefused",
    "FeedUnavailable",
    "Frame",
    "HandState",
    "Hands",
    "Person",
    "RawBody",
    "Rotations",
    "Skeleton",
    "SyncFeedClient",
    "feed_url",
]
