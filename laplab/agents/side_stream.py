"""A second stream of torch work for a learner whose gradient step has two independent halves.

PPO's policy and value networks (camera models: a trunk each) and SAC's actor and critic with
separate trunks share no trained parameter, so one half's forward, backward and optimizer work can
run on a second thread while the calling thread runs the other's, each with half of torch's intra-op
threads. On this project's 2-core host two independent streams keep both cores busier than two
threads meeting at the end of every operation (BENCHMARKS.md, sessions 6 and 11).
"""

from __future__ import annotations

import contextlib
import os
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, Callable, Iterator

import torch


def _finished(fn: Callable[[], Any]) -> Future:
    """``fn()`` run at once, as a finished ``Future``."""
    future: Future = Future()
    try:
        future.set_result(fn())
    except BaseException as error:  # noqa: BLE001 - handed to whoever reads the result
        future.set_exception(error)
    return future


class RunOnSide:
    """``side(fn) -> Future``: where a step's side half runs. ``side.all_threads()`` gives the calling
    thread all of the learner's torch threads for work done while the side thread is idle (an
    optimizer step after both halves joined: Adam on one thread took twice as long as on two)."""

    def __init__(self, submit: Callable[[Callable[[], Any]], Future], threads: int | None = None):
        self._submit = submit
        self._threads = threads  # the caller's count before the stream opened; None: nothing to give

    def __call__(self, fn: Callable[[], Any]) -> Future:
        return self._submit(fn)

    @contextlib.contextmanager
    def all_threads(self) -> Iterator[None]:
        if self._threads is None:
            yield
            return
        kept = torch.get_num_threads()
        torch.set_num_threads(self._threads)
        try:
            yield
        finally:
            torch.set_num_threads(kept)


run_now = RunOnSide(_finished)  # the stream of a one-thread learner: ``fn()`` at once


class SideStream:
    """One learner's second thread, made on first use (and again in a forked child, which has none)."""

    def __init__(self, name: str):
        self.name = name
        self._pool: tuple[int, ThreadPoolExecutor] | None = None  # (process id, pool of one thread)

    def __getstate__(self) -> dict[str, Any]:  # a copied or pickled learner makes its own thread
        return {"name": self.name, "_pool": None}

    @contextlib.contextmanager
    def open(self) -> Iterator[RunOnSide]:
        """A ``run(fn) -> Future`` for the side half of the steps made inside: with two or more torch
        threads, ``fn`` runs on the second thread with half of them (the caller keeps the rest, and
        gets its thread count back on leaving); with one, it runs at once. Grad mode and autocast
        are per thread: ``fn`` starts with grad enabled and no autocast."""
        threads = torch.get_num_threads()
        if threads < 2:
            yield run_now
            return
        side_threads = threads // 2
        if self._pool is None or self._pool[0] != os.getpid():
            self._pool = (os.getpid(), ThreadPoolExecutor(1, thread_name_prefix=self.name))
        pool = self._pool[1]

        def on_side(fn: Callable[[], Any]) -> Any:
            if torch.get_num_threads() != side_threads:  # a thread's own count (OpenMP), set once
                torch.set_num_threads(side_threads)
                torch.set_flush_denormal(True)  # inherited from the learner's thread; per thread too
            return fn()

        torch.set_num_threads(threads - side_threads)
        try:
            yield RunOnSide(lambda fn: pool.submit(on_side, fn), threads)
        finally:
            pool.submit(lambda: None).result()  # after a failure, nothing of this update still runs
            torch.set_num_threads(threads)
