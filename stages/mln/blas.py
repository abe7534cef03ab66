"""One BLAS thread while a learner optimises.

OpenBLAS splits even small products over its threads; on a busy machine each split waits for a free core.
Measured on this project's 2-core machines while other jobs ran: scipy's L-BFGS-B on 168 weights took
7.8 ms per iteration with OpenBLAS's 2 threads and 0.16 ms with one. The learners' products are small
(hundreds of weights, chains of 7 classes), so one thread is also the fast choice on an idle machine.
As threadpoolctl does (without the dependency): the OpenBLAS libraries that numpy and scipy loaded are
found in the process's memory map, set to one thread, and restored afterwards. Where none is found
(another BLAS, another system), nothing changes. A block inside another keeps the outer block's setting: reading
the memory map costs about 2 ms, and a caller running many learners (conflate's cross-validation) opens one block.
"""

from __future__ import annotations

import contextlib
import ctypes
import threading
from collections.abc import Iterator

_NAMES = ("openblas", "scipy_openblas", "scipy_openblas64_")  # prefixes of <prefix>_set_num_threads (+ suffix)
_open = [0]  # one_thread blocks open in this process (the thread count is the process's)
_lock = threading.Lock()


def _libraries() -> list[tuple[ctypes._CFuncPtr, ctypes._CFuncPtr]]:
    """(set_num_threads, get_num_threads) of every OpenBLAS loaded in this process."""
    try:
        with open("/proc/self/maps", encoding="utf-8") as maps:
            paths = sorted({line.split()[-1] for line in maps if "openblas" in line.lower() and "/" in line})
    except OSError:
        return []
    found = []
    for path in paths:
        try:
            library = ctypes.CDLL(path)
        except OSError:
            continue
        for prefix in _NAMES:
            suffix = "64_" if prefix.endswith("64_") else ""
            base = prefix.removesuffix("64_")
            setter = getattr(library, f"{base}_set_num_threads{suffix}", None)
            getter = getattr(library, f"{base}_get_num_threads{suffix}", None)
            if setter is not None and getter is not None:
                found.append((setter, getter))
                break
    return found


@contextlib.contextmanager
def one_thread() -> Iterator[None]:
    """Run the block with every loaded OpenBLAS on one thread (inside another block: as that one left it)."""
    with _lock:
        _open[0] += 1
        libraries = _libraries() if _open[0] == 1 else []
        before = [getter() for _, getter in libraries]
        for setter, _ in libraries:
            setter(1)
    try:
        yield
    finally:
        with _lock:
            _open[0] -= 1
            for (setter, _), threads in zip(libraries, before):
                setter(threads)
