"""Open Sound Control 1.0 encoding: messages, bundles, and bundles packed to fit one datagram.

OSC 1.0 (opensoundcontrol.stanford.edu/spec-1_0): every string is ASCII, NUL-terminated and
padded with NULs to a multiple of 4 bytes; numbers are big-endian. A message is its address, its
type tag string (``,`` then one letter per argument) and its arguments; a bundle is ``#bundle``,
a 64-bit NTP time tag and its elements, each preceded by its size as an int32. The types written
here: ``i`` int32, ``f`` float32, ``d`` float64 (times: a float32 of Unix seconds is off by up to
a minute), ``s`` string.

The encoder is written here rather than taken from python-osc (a dependency for a hundred lines);
the tests read what it writes with python-osc, an independent decoder.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence
from typing import Final

MAX_DATAGRAM: Final = 1472
"""UDP payload bytes that fit a 1,500-byte Ethernet MTU without IP fragmentation (1500 - 20
IPv4 - 8 UDP): a fragment lost loses the whole datagram."""
IMMEDIATELY: Final = 1
"""The time tag that means "now" (OSC 1.0): receivers dispatch the bundle on arrival."""
_BUNDLE_HEAD: Final = b"#bundle\x00"

Argument = int | float | str


class OscError(ValueError):
    """A value OSC cannot carry as asked (a non-ASCII string, an element over the size limit)."""


def _string(text: str) -> bytes:
    try:
        raw = text.encode("ascii")
    except UnicodeEncodeError as exc:
        raise OscError(f"OSC strings are ASCII: {text!r}") from exc
    return raw + b"\x00" * (4 - len(raw) % 4)


def message(address: str, types: str, args: Sequence[Argument]) -> bytes:
    """One OSC message.

    Args:
        address: ``/``-separated, ASCII.
        types: one letter per argument: ``i`` int32, ``f`` float32, ``d`` float64, ``s`` string.
        args: the arguments, in order.

    Raises:
        OscError: a type letter not in ``ifds``, a count that does not match, a non-ASCII string.
        struct.error: an int outside int32.
    """
    if len(types) != len(args):
        raise OscError(f"{address}: {len(types)} type tags for {len(args)} arguments")
    parts = [_string(address), _string("," + types)]
    numeric = "".join(t for t in types if t != "s")
    if "s" not in types:  # the common case: one struct call for every argument
        if set(numeric) - set("ifd"):
            raise OscError(f"{address}: unsupported OSC type in {types!r}")
        parts.append(struct.pack(">" + types, *args))
        return b"".join(parts)
    for tag, value in zip(types, args, strict=True):
        if tag == "s":
            parts.append(_string(str(value)))
        elif tag in "ifd":
            parts.append(struct.pack(">" + tag, value))
        else:
            raise OscError(f"{address}: unsupported OSC type {tag!r}")
    return b"".join(parts)


def bundle(elements: Iterable[bytes], time_tag: int = IMMEDIATELY) -> bytes:
    """A bundle of encoded messages (or bundles); ``time_tag``: NTP 64-bit fixed point."""
    parts = [_BUNDLE_HEAD, struct.pack(">Q", time_tag)]
    for element in elements:
        parts.append(struct.pack(">i", len(element)))
        parts.append(element)
    return b"".join(parts)


def pack_bundles(
    elements: Sequence[bytes], limit: int = MAX_DATAGRAM, time_tag: int = IMMEDIATELY
) -> list[bytes]:
    """``elements`` in order, in as few bundles of at most ``limit`` bytes each as greedy
    filling gives (each bundle a datagram of its own).

    Raises:
        OscError: one element alone does not fit a bundle of ``limit`` bytes.
    """
    overhead = len(_BUNDLE_HEAD) + 8
    out: list[bytes] = []
    current: list[bytes] = []
    size = overhead
    for element in elements:
        need = 4 + len(element)
        if overhead + need > limit:
            raise OscError(f"an OSC element of {len(element)} bytes cannot fit {limit} bytes")
        if size + need > limit:
            out.append(bundle(current, time_tag))
            current, size = [], overhead
        current.append(element)
        size += need
    if current:
        out.append(bundle(current, time_tag))
    return out
