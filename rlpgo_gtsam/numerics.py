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

Stack. GTSAM's elimination walks its Bayes tree recursively (``BayesTree::fillNodesIndex``,
about 100 bytes of stack a level), and a tree is as deep as the elimination order makes it:
on a 100,000-pose chain with a closure every 1000 poses COLAMD gives a tree 87,000 levels
deep, past the main thread's 8 MiB, and the process dies of SIGSEGV (GTSAM's own LM from
Python does the same). :func:`eliminating_call` runs such a call where the stack holds the
graph's deepest tree (:func:`elimination_stack_bytes`): in place where the calling thread's
stack is known to, else on a thread started with that stack. The same ordering and the
same numbers, only a stack deep enough for them.

Memory. glibc's malloc keeps what a large graph's temporaries freed (GTSAM's linearized
graph and Bayes tree, SciPy's factorizations) on its free lists, scattered between live
blocks, and the next step does not reuse most of it: on 2 poses joined by 10^6 edges each
comparison row left 150-600 MB more resident than the one before (2.78 GB in all). After
an elimination or a row of a large graph (:data:`RELEASE_SIZE` variables and factors or
more) :func:`release_free_memory` hands those pages back (``malloc_trim``: 2-7 ms and
page faults after, which the shared benchmark files, all smaller, never pay).
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

__all__ = ["numeric_call", "bounded_threads", "one_thread_from_start", "eliminating_call",
           "elimination_stack_bytes", "release_free_memory", "RELEASE_SIZE",
           "USER_THREAD_VARIABLES"]

USER_THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                         "BLIS_NUM_THREADS", "VECLIB_MAXIMUM_THREADS")
_F = TypeVar("_F", bound=Callable[..., Any])
_T = TypeVar("_T")
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


# A tree level took 80-100 bytes of stack (chains of 40,000 poses, planar and 3D, LM and
# InitializePose3: 3 MiB crashed, 5 MiB ran); 256 a variable is 2.5 times that, and the
# base holds the frames above the recursion.
_STACK_PER_VARIABLE = 256
_STACK_BASE = 1 << 20
# A thread started for an elimination has at least what a main thread usually has.
_THREAD_STACK_MIN = 8 << 20
_stack_size_lock = threading.Lock()  # threading.stack_size is process-wide: set, start, restore


def elimination_stack_bytes(variables: int) -> int:
    """The stack an elimination of ``variables`` variables is given: 1 MiB plus 256 bytes
    a variable (2.5 times what the deepest tree, one level a variable, took), in whole MiB.
    """
    size = _STACK_BASE + _STACK_PER_VARIABLE * max(0, int(variables))
    return -(-size // (1 << 20)) << 20


def eliminating_call(variables: int, function: Callable[[], _T], factors: int = 0) -> _T:
    """``function()``: a GTSAM call that eliminates a graph of ``variables`` variables and
    ``factors`` factors (an optimizer's ``optimize``, Shonan's ``run``,
    ``InitializePose3``, LAGO), on a stack of :func:`elimination_stack_bytes` at least;
    returns its result or raises its exception, then releases the free memory of a large
    graph (:func:`release_free_memory`).

    Where the calling thread's stack is known to hold that (the main thread's limit, or a
    thread started here) it runs in place: every shared benchmark file does. Otherwise it
    runs on a thread started with that stack (8 MiB at least) while the caller waits.
    Raises RuntimeError where the system refuses a thread of that stack.
    """
    try:
        return _on_deep_stack(variables, function)
    finally:
        release_free_memory(variables + factors)


def _stack_here() -> int:
    """The calling thread's stack in bytes where it is known: a thread started by
    :func:`eliminating_call`, or the main thread (its resource limit); 0 otherwise."""
    started = getattr(_inside, "stack", 0)
    if started or threading.current_thread() is not threading.main_thread():
        return started
    try:
        import resource
    except ImportError:  # no resource limits to read (Windows)
        return 0
    limit = resource.getrlimit(resource.RLIMIT_STACK)[0]
    return 1 << 62 if limit == resource.RLIM_INFINITY else limit


def _on_deep_stack(variables: int, function: Callable[[], _T]) -> _T:
    size = elimination_stack_bytes(variables)
    if _stack_here() >= size:
        return function()
    size = max(size, _THREAD_STACK_MIN)
    outcome: list[Any] = []

    def run() -> None:
        _inside.stack = size
        try:
            outcome.append((True, function()))
        except BaseException as error:  # handed to the caller, raised there
            outcome.append((False, error))

    # a daemon: a caller interrupted while it waits (Ctrl-C) can exit without joining it
    worker = threading.Thread(target=run, name="rlpgo-elimination", daemon=True)
    with _stack_size_lock:
        previous = threading.stack_size(size)
        try:
            worker.start()
        except RuntimeError as error:
            raise RuntimeError(f"cannot start a thread with {size >> 20} MiB of stack for "
                               f"the elimination of {variables} variables ({error})") from None
        finally:
            threading.stack_size(previous)
    worker.join()
    succeeded, result = outcome[0]
    if not succeeded:
        raise result
    return result  # type: ignore[no-any-return]


# Variables and factors from which a step's freed memory is handed back: City10K, the
# largest shared planar file, has 30,697; 10^6 parallel edges freed 600 MB a row.
RELEASE_SIZE = 100_000
_trim: list[Any] = []  # glibc's malloc_trim, or None where the C library has none


def release_free_memory(size: int) -> None:
    """After a step on a problem of ``size`` variables and factors, at least
    :data:`RELEASE_SIZE` of them: hand the C heap's free pages back to the system (glibc's
    ``malloc_trim(0)``; nothing where the C library has no such call)."""
    if size < RELEASE_SIZE:
        return
    if not _trim:
        import ctypes

        try:
            _trim.append(ctypes.CDLL(None).malloc_trim)
        except (AttributeError, OSError):
            _trim.append(None)
    if _trim[0] is not None:
        _trim[0](0)
