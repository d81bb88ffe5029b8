"""Single-threaded BLAS while solving.

The stick and abstraction solvers make thousands of small linear-algebra calls
(L-BFGS-B's updates on ~50 variables, 3x3 products, Cholesky factorizations of ~100x100
systems). OpenBLAS's thread hand-offs cost far more than such calls: on
two shared cores L-BFGS-B ran 20 times slower with two BLAS threads than with one. This
context manager sets the OpenBLAS libraries bundled with numpy and scipy to one thread and
restores them afterwards; it does nothing where they cannot be found.

A second core is used by a thread instead (no processes: safe inside Blender), where
numpy spends long stretches with the GIL released: under :func:`row_threads` ``(2)``,
:func:`split_rows` evaluates a large population in two fixed chunks of rows, one in a
shared worker thread, and :func:`in_background` runs an independent task in that thread
while the caller goes on. Small arrays gain nothing (the GIL changes hands at every numpy
call): callers split only populations of hundreds of rows.
"""

from __future__ import annotations

import ctypes
import glob
import os
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any

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


# -- two row chunks in two threads ----------------------------------------------------------

#: Rows a chunk boundary is a multiple of (of a smaller power of two below twice as many
#: rows): the rows of each chunk then meet the same unrolled and tail loops of numpy's
#: and OpenBLAS's kernels as in one call.
ROW_ALIGN = 64

_local = threading.local()
_executor: ThreadPoolExecutor | None = None
_executor_lock = threading.Lock()


def _worker() -> ThreadPoolExecutor:
    """The one worker thread shared by every split (started on first use)."""
    global _executor
    with _executor_lock:
        if _executor is None:
            _executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="gesture_pose")
        return _executor


@contextmanager
def row_threads(threads: int) -> Iterator[None]:
    """Let :func:`split_rows` in this thread use ``threads`` threads (1 or 2) meanwhile.

    Args:
        threads: 1 (every call in this thread) or 2 (two fixed chunks, one in a worker).
    """
    if threads not in (1, 2):
        raise ValueError(f"threads must be 1 or 2, not {threads!r}")
    previous = getattr(_local, "threads", 1)
    _local.threads = threads
    try:
        yield
    finally:
        _local.threads = previous


def _join(parts: tuple[Any, Any]) -> Any:
    """The two chunks' results joined along the first axis (arrays, tuples, dicts)."""
    a, b = parts
    if isinstance(a, numpy.ndarray):
        return numpy.concatenate([a, b])
    if isinstance(a, tuple):
        return tuple(_join(p) for p in zip(a, b, strict=True))
    if isinstance(a, dict):
        return {k: _join((a[k], b[k])) for k in a}
    if a is None:
        return None
    raise TypeError(f"cannot join results of type {type(a).__name__}")


def split_rows(fn: Callable[..., Any], *arrays: numpy.ndarray, min_rows: int = 2 * ROW_ALIGN
               ) -> Any:
    """``fn(*arrays)`` evaluated on two fixed chunks of rows in two threads, joined.

    Under :func:`row_threads` ``(2)`` with at least ``min_rows`` rows, the rows are cut at
    the multiple of :data:`ROW_ALIGN` (or of a smaller power of two) nearest half of
    them (fixed by the row count, not by scheduling): the second chunk runs in the
    calling thread while the shared worker thread runs the first; numpy releases the GIL
    in large array operations, so the two overlap. Otherwise (and inside a chunk: no
    nesting) it is ``fn(*arrays)``. ``fn`` must treat its rows independently (row-wise
    operations); its results, arrays with a leading row axis (or tuples and dicts of
    them, or None), are concatenated: equal to one call's when its operations give every
    row the same arithmetic.

    Args:
        fn: ``(*arrays with N rows) -> result with N rows``.
        *arrays: Arrays with the same first dimension ``N``.
        min_rows: Fewer rows run in one call.

    Returns:
        The joined result.
    """
    n = len(arrays[0])
    if not _may_use_worker() or n < min_rows:
        return fn(*arrays)
    align = ROW_ALIGN
    while align > 1 and n < 2 * align:
        align //= 2
    cut = min(max(align, align * round(n / (2 * align))), n - 1)
    first = tuple(a[:cut] for a in arrays)
    second = tuple(numpy.array(a[cut:]) for a in arrays)

    future = _worker().submit(_inside, fn, *first)
    try:
        mine = _inside(fn, *second)
    finally:
        theirs = future.result()
    return _join((theirs, mine))


def _may_use_worker() -> bool:
    """Whether this thread may hand work to the worker now (see :func:`row_threads`)."""
    return (getattr(_local, "threads", 1) >= 2 and not getattr(_local, "inside", False)
            and _pending == 0)


def _inside(fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)``, any split or background task it asks for run in this thread."""
    before = getattr(_local, "inside", False)
    _local.inside = True
    try:
        return fn(*args)
    finally:
        _local.inside = before


class _Done:
    """A result already computed, read as a future's."""

    def __init__(self, value: Any) -> None:
        self._value = value

    def result(self) -> Any:
        """The value."""
        return self._value


_pending = 0


def _finished(_: Future) -> None:
    """One background task fewer."""
    global _pending
    with _executor_lock:
        _pending -= 1


def in_background(fn: Callable[..., Any], *args: Any) -> Future | _Done:
    """``fn(*args)`` started in the worker thread, its result read later.

    Under :func:`row_threads` ``(2)`` (and not inside a chunk) the worker runs it while
    the caller goes on; meanwhile :func:`split_rows` runs in one thread (the worker is
    taken). Otherwise it is computed now. Either way ``.result()`` gives ``fn(*args)``.

    Args:
        fn: The task; it must not depend on what the caller does meanwhile.
        *args: Its arguments.

    Returns:
        A future (or an already computed value) with ``result()``.
    """
    global _pending
    if not _may_use_worker():
        return _Done(fn(*args))
    with _executor_lock:
        _pending += 1
    future = _worker().submit(_inside, fn, *args)
    future.add_done_callback(_finished)
    return future
