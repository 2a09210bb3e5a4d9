"""The test suite. Imported before any test module, so before numpy loads: see
:mod:`tests.numeric_paths`, which pins numpy's and OpenBLAS's code paths on an AVX-512 host so
that the compiled kernels can be checked against numpy to the bit there too."""

from tests.numeric_paths import pin_numeric_paths

pin_numeric_paths()
