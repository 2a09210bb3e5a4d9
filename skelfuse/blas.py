"""One BLAS thread per process: the fusion server's numpy calls are small and 30 times a second.

With about nine or more views of a person, a matrix product inside the fusion step is big
enough for OpenBLAS to wake its worker threads, which then busy-wait between the 30 Hz calls and
take a whole core of a small machine (issue 11: 166 % server CPU and 306 lost output instants
in 120 s on two cores, against 86 % and 2 with one thread). Nothing in skelfuse gains from BLAS
threads, so every process pins them to one.

This module is a process setting in the bottom layer (it imports nothing of skelfuse): the
command line (:func:`skelfuse.cli.main`) calls :func:`pin_blas_threads` before any command runs,
so ``skelfuse server``, ``replay``, ``export``, ``demo`` and ``agent`` are all covered. A program
that embeds ``FusionEngine`` or the server app itself calls it once at start.
"""

from __future__ import annotations

import logging
import os
from typing import Final

from threadpoolctl import threadpool_info, threadpool_limits

logger = logging.getLogger(__name__)

BLAS_THREAD_VARIABLES: Final = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")
"""What OpenBLAS, MKL and BLIS read when they load: set for libraries not loaded yet (SciPy
brings its own OpenBLAS on first use) and for child processes."""


def pin_blas_threads() -> list[dict[str, object]]:
    """Limit every BLAS library of this process, loaded now or later, to one thread.

    Libraries already loaded (numpy's) are limited through threadpoolctl; the environment
    variables above cover those loaded afterwards and child processes. The limit lasts for the
    process. Logs at debug level what was pinned.

    Returns:
        threadpoolctl's description of each BLAS library loaded now (``filepath``,
        ``internal_api``, ``num_threads`` ...), after pinning.
    """
    for name in BLAS_THREAD_VARIABLES:
        os.environ[name] = "1"
    # A plain call, not a context manager: the limit is meant to outlive this function.
    threadpool_limits(limits=1, user_api="blas")
    pinned = [info for info in threadpool_info() if info.get("user_api") == "blas"]
    for info in pinned:
        logger.debug(
            "BLAS pinned: %s (%s %s) at %s thread(s)",
            info.get("filepath"), info.get("internal_api"), info.get("version"),
            info.get("num_threads"),
        )  # fmt: skip
    if not pinned:
        logger.debug("BLAS pinned: no BLAS library loaded yet; %s set to 1", BLAS_THREAD_VARIABLES)
    return pinned
