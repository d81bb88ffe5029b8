"""Single-threaded BLAS while solving.

The stick and abstraction solvers make thousands of small linear-algebra calls
(L-BFGS-B's updates on ~50 variables, 3x3 products, Cholesky factorizations of ~100x100
systems). OpenBLAS's thread hand-offs cost far more than such calls: on
two shared cores L-BFGS-B ran 20 times slower with two BLAS threads than with one. This
context manager sets the OpenBLAS libraries bundled with numpy and scipy to one thread and
restores them afterwards; it does nothing where they cannot be found.
"""

from __future__ import annotations

import ctypes
import glob
import os
from collections.abc import Iterator
from contextlib import contextmanager

import numpy
import scipy

#: (library glob relative to site-packages, setter name, getter name).
_CANDIDATES = (
    ("scipy.libs/*openblas*", "scipy_openblas_set_num_threads",
     "scipy_openblas_get_num_threads"),
    ("scipy/.dylibs/*openblas*", "scipy_openblas_set_num_threads",
     "scipy_openblas_get_num_threads"),
    ("numpy.libs/*openblas*", "openblas_set_num_threads64_", "openblas_get_num_threads64_"),
    ("numpy/.dylibs/*openblas*", "openblas_set_num_threads64_",
     "openblas_get_num_threads64_"),
)


def _controls() -> list[tuple]:
    """``(setter, getter)`` pairs of the OpenBLAS libraries found."""
    out = []
    roots = {os.path.dirname(os.path.dirname(numpy.__file__)),
             os.path.dirname(os.path.dirname(scipy.__file__))}
    for root in roots:
        for pattern, set_name, get_name in _CANDIDATES:
            for path in glob.glob(os.path.join(root, pattern)):
                try:
                    lib = ctypes.CDLL(path)
                    out.append((getattr(lib, set_name), getattr(lib, get_name)))
                except (OSError, AttributeError):
                    continue
    return out


@contextmanager
def single_thread_blas() -> Iterator[None]:
    """Run the body with one OpenBLAS thread, then restore the previous counts."""
    controls = _controls()
    previous = []
    for setter, getter in controls:
        try:
            previous.append((setter, int(getter())))
            setter(1)
        except (OSError, ValueError):
            continue
    try:
        yield
    finally:
        for setter, count in previous:
            setter(count)
