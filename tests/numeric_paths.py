"""numpy's and OpenBLAS's code paths for the test session, chosen before numpy loads.

The compiled fusion kernels (numba) are checked against numpy to the bit (tests/unit/
test_kernels*.py, test_bone_fit_bits.py, test_label_scores.py). They reproduce numpy's AVX2
code paths. On a host with AVX-512 (seen on 2026-11-24: 38 of those tests failed there, by one
or two units in the last place) numpy dispatches other loops and OpenBLAS another kernel:

- numpy's AVX-512 loops for ``exp``, ``log``, ``power``, ``arctan2``, ``arccos`` and the other
  transcendental functions (SVML) round differently from its AVX2 ones;
- OpenBLAS's SkylakeX ``ddot``, behind ``np.vecdot``, adds in another order than its Haswell
  one.

So on such a host the session disables numpy's AVX-512 dispatch (``NPY_DISABLE_CPU_FEATURES``:
the names numpy itself reports, which change between numpy versions) and selects OpenBLAS's
Haswell kernels (``OPENBLAS_CORETYPE``); subprocesses the tests start inherit both. Outside the
tests nothing is pinned: there the numpy fallback and the kernels may differ in the last bits on
such a host (docs/fusion.md "Compiled kernels"). A variable already set is left as it is. On a
host without AVX-512 nothing is set. The mono source's environment (`.venv-mono`, numpy 1.26,
started by its integration test) inherits the numpy variable too; it disables the names it
knows (``AVX512_ICL``) and passes over the others with an ``ImportWarning``.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

_REPORT = """
try:
    from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
except ImportError:  # numpy 1.x
    from numpy.core._multiarray_umath import __cpu_dispatch__, __cpu_features__
print(" ".join(name for name in __cpu_dispatch__
               if (name.startswith("AVX512") or name == "X86_V4") and __cpu_features__.get(name)))
"""
"""Prints numpy's dispatched AVX-512 targets that this host supports (run in a child process:
this one must not load numpy before the variables are set)."""


def has_avx512() -> bool:
    """Whether this host's CPU reports AVX-512F (Linux's /proc/cpuinfo; elsewhere: no)."""
    try:
        flags = Path("/proc/cpuinfo").read_text(encoding="utf-8")
    except OSError:
        return False
    return " avx512f" in flags


def pin_numeric_paths() -> None:
    """Set the two variables (module docstring) on an AVX-512 host, before numpy loads.

    Raises:
        RuntimeError: numpy is loaded already (a plugin imported it): the pin would not apply.
    """
    if not has_avx512():
        return
    if "NPY_DISABLE_CPU_FEATURES" in os.environ and "OPENBLAS_CORETYPE" in os.environ:
        return  # set already: by the user, or inherited (a worker process a test started)
    if "numpy" in sys.modules:
        raise RuntimeError(
            "numpy was imported before tests/__init__.py could pin its code paths "
            "(tests/numeric_paths.py); the kernel bit-checks would compare other loops"
        )
    if "NPY_DISABLE_CPU_FEATURES" not in os.environ:
        report = subprocess.run(
            [sys.executable, "-c", _REPORT], capture_output=True, text=True, check=True
        )
        os.environ["NPY_DISABLE_CPU_FEATURES"] = report.stdout.strip()  # "": none to disable
    os.environ.setdefault("OPENBLAS_CORETYPE", "Haswell")
