"""What a learner sets in its process's torch runtime: intra-op threads, glibc's memory reuse, and
flush-to-zero of denormal floats (each process-wide or per thread, as its docstring says)."""

from __future__ import annotations

import ctypes
import os

import torch


def usable_cores() -> int:
    """The CPUs this process may run on (its affinity where the OS tells it, else the machine's)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def limit_torch_threads(num_threads: int | None = None) -> None:
    """Set torch's intra-op threads to ``num_threads``, or (None) to the CPUs this process may use,
    at most ``$OMP_NUM_THREADS`` when set (so learners in worker processes do not oversubscribe the
    machine, and a camera learner built after a one-thread vector learner in the same process gets
    its cores back)."""
    available = usable_cores()
    omp = os.environ.get("OMP_NUM_THREADS", "")
    if omp.isdigit() and int(omp) > 0:
        available = min(available, int(omp))
    torch.set_num_threads(max(1, int(num_threads)) if num_threads is not None else available)


def keep_freed_memory() -> bool:
    """Ask glibc's malloc to keep freed memory for reuse rather than hand it back to the OS.

    A camera network's minibatch allocates and frees tensors of tens of MB (the 11,264 x 512 dense
    weights cast to bfloat16, their gradients); glibc maps each afresh and page-faults through it,
    which made a quarter of a bfloat16 minibatch. Keeping the memory makes those minibatches ~15-25 %
    faster (bench/time_to_lap.py --sensor FRONT_FACING_CAMERA). Process-wide; returns whether it took
    (False off glibc, e.g. macOS, where nothing changes)."""
    import ctypes.util
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_top_pad, m_mmap_threshold = -1, -2, -3
    return all(mallopt(option, value) == 1 for option, value in (
        (m_mmap_threshold, 1 << 30), (m_trim_threshold, 1 << 30), (m_top_pad, 64 << 20)))


def flush_denormals() -> bool:
    """Flush denormal floats (below 1.2e-38) to zero, as TensorFlow, DeepRacer's framework, computes on
    the CPU: in this thread, in the OpenMP worker threads it already has and in every thread started
    from it later (x86's FTZ/DAZ flags are per thread; a new thread inherits its creator's). Trained
    camera networks carry denormals in their gradients and Adam's moments, which made gradient steps
    ~1.3x slower late in a training (BENCHMARKS.md, session 14). Returns whether the CPU has the flags."""
    supported = bool(torch.set_flush_denormal(True))
    if supported:
        _flush_denormals_in_openmp_workers()
    return supported


def _flush_denormals_in_openmp_workers() -> None:
    """The flags in the worker threads of this thread's OpenMP team, which exist before any learner:
    numba's parallel simulator shares torch's libgomp and starts the team on its first step (those
    threads took the flags the thread had then). Each runs ``torch.set_flush_denormal`` once, in a
    parallel region of the libgomp torch uses; nothing happens where torch has no libgomp."""
    library = os.path.join(os.path.dirname(torch.__file__), "lib", "libgomp.so.1")
    if not os.path.exists(library):
        return
    try:
        gomp = ctypes.CDLL(library)  # loaded already by torch: the same library and its thread pools
        body_type = ctypes.CFUNCTYPE(None, ctypes.c_void_p)
        parallel = gomp.GOMP_parallel  # void GOMP_parallel(void (*fn)(void *), void *data, unsigned n, unsigned flags)
        parallel.argtypes = (body_type, ctypes.c_void_p, ctypes.c_uint, ctypes.c_uint)
        parallel.restype = None
    except (OSError, AttributeError):
        return
    body = body_type(lambda _: torch.set_flush_denormal(True))
    threads = max(usable_cores(), torch.get_num_threads())  # the most either runtime's team asks of this thread
    parallel(body, None, threads, 0)
