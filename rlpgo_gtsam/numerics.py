"""How the library's hot calls treat the numeric libraries: bounded threads, quiet numpy.

Threads. The relaxation, the translation step and the robust path spend their time in sparse
factorizations and small dense blocks; OpenBLAS's and OpenMP's worker threads gain nothing
there and, when another process holds a core, spin: City10K's certified stage took 26-28 s
instead of 2 s next to one CPU-bound process. Inside a hot call (:func:`numeric_call`) the
BLAS and OpenMP pools are limited to one thread through threadpoolctl, and restored after.
A user's own setting wins: with any of ``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS``,
``MKL_NUM_THREADS``, ``BLIS_NUM_THREADS`` or ``VECLIB_MAXIMUM_THREADS`` in the environment,
or ``RLPGO_THREADS`` (a number, or ``auto`` for the libraries' defaults), the pools are left
as the user set them. A command that calls :func:`one_thread_from_start` before numpy loads
(``rlpgo-init``, ``rlpgo-compare``) starts OpenBLAS with one thread instead (same limit, and
OpenBLAS does not start and spin workers it would not use: about 0.05 s of a small graph's
run).

Floating point. Overflow or an invalid operation on extreme (finite) input is caught where it
matters by explicit finiteness checks that raise the package's errors; numpy's warnings for
them (printed as source excerpts, and tracebacks under ``-W error``) are switched off inside
a hot call.
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

__all__ = ["numeric_call", "bounded_threads", "one_thread_from_start", "USER_THREAD_VARIABLES"]

USER_THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                         "BLIS_NUM_THREADS", "VECLIB_MAXIMUM_THREADS")
_F = TypeVar("_F", bound=Callable[..., Any])
_controller: list[Any] = []  # threadpoolctl's controller, made once on first use
_started_bounded: list[bool] = []  # one_thread_from_start set this process's pools
_inside = threading.local()  # depth: whether this thread is inside a bounded block


def _thread_limit() -> int | None:
    """Threads for the pools inside a hot call, or None to leave them as they are."""
    if _started_bounded:
        return None  # the pools started with one thread: nothing to limit
    setting = os.environ.get("RLPGO_THREADS", "").strip()
    if setting:
        return None if setting == "auto" else max(1, int(setting))
    if any(os.environ.get(name) for name in USER_THREAD_VARIABLES):
        return None
    return 1


def one_thread_from_start() -> None:
    """Where the user set none of the thread variables (nor ``RLPGO_THREADS``), set
    ``RLPGO_THREADS=1`` (the limit hot calls use anyway), ``OPENBLAS_NUM_THREADS=1`` and
    ``OMP_NUM_THREADS=1`` in this process's environment: called before numpy loads, OpenBLAS
    (numpy's and SciPy's copies) and any OpenMP runtime loaded later start with one thread,
    and the hot calls skip threadpoolctl (finding the loaded libraries took 0.017-0.027 s
    here, a few percent of a small file's run). For a command's process (its children
    inherit the setting); this module imports no numpy at its top for that reason."""
    if os.environ.get("RLPGO_THREADS", "").strip() or any(
            os.environ.get(name) for name in USER_THREAD_VARIABLES):
        return  # as _thread_limit reads them
    os.environ["RLPGO_THREADS"] = "1"
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    os.environ["OMP_NUM_THREADS"] = "1"
    _started_bounded.append(True)


@contextmanager
def bounded_threads() -> Iterator[None]:
    """BLAS and OpenMP pools limited to :func:`_thread_limit` threads inside the block; a
    block inside another of the same thread leaves them as the outer one set them
    (threadpoolctl's limit and restore took 0.06 ms CPU a call: ``Certified3D.run`` and the
    ``synchronize`` inside it paid it twice on every graph).

    Each library's pool is read and set through threadpoolctl's per-library controllers
    (the libraries found once), and put back as it was on the way out: what
    ``ThreadpoolController.limit`` does, without rebuilding its record of every library at
    each call (tinyGrid3D's ``Certified3D.run``, median of 2000: 2.56 -> 2.46 ms CPU)."""
    if getattr(_inside, "depth", 0):
        yield
        return
    limit = _thread_limit()
    if limit is None:
        yield
        return
    _inside.depth = 1
    try:
        if not _controller:
            # SciPy's own OpenBLAS (its LAPACK, ARPACK, cho_factor) loads with scipy.linalg:
            # a controller made before it was loaded left its pools at their defaults (a
            # 125-pose relaxation took 0.74 s CPU instead of 0.05 s beside another busy
            # process)
            import scipy.linalg  # noqa: F401
            from threadpoolctl import ThreadpoolController

            _controller.append(ThreadpoolController())
        libraries = _controller[0].lib_controllers
        before = [library.num_threads for library in libraries]
        try:
            for library in libraries:
                library.set_num_threads(limit)
            yield
        finally:
            for library, threads in zip(libraries, before, strict=True):
                library.set_num_threads(threads)
    finally:
        _inside.depth = 0


def numeric_call(function: _F) -> _F:
    """Decorate a hot call: bounded threads and numpy's floating-point warnings off."""

    import numpy as np  # not at the top: see one_thread_from_start

    @functools.wraps(function)
    def call(*args: Any, **kwargs: Any) -> Any:
        with bounded_threads(), np.errstate(all="ignore"):
            return function(*args, **kwargs)

    return call  # type: ignore[return-value]
