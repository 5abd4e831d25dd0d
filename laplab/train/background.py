"""The model folder's writes on one background thread, so the next iteration does not wait for them.

Writing an iteration's files (simtrace CSV, TrainingMetrics.json, the checkpoint with its resume
state: serialised, compressed, fsync'ed and renamed into place) took 0.4 s of a GPU iteration. The
trainer hands those events to :class:`BackgroundListeners`, which passes them, in the order they
came, to the listeners it wraps (the folder's recorders) on one thread of its own; the trainer goes
on collecting meanwhile. The files are written exactly as before (same order, same atomic renames,
same fsyncs), one iteration later in wall time.

Rules that keep it as safe as writing in the trainer's thread:

- the events are snapshots: a checkpoint's tensors are copied when it is made
  (:func:`laplab.train.trainer.checkpoint_writer`), episodes are fresh arrays per iteration;
- :meth:`BackgroundListeners.wait` returns once everything handed over is written: the trainer calls
  it at the end of :meth:`~laplab.train.trainer.Trainer.run` (every way it ends: limits, Stop, a
  reward error, a crash), after checkpoint 0, and in :meth:`~laplab.train.trainer.Trainer.close`;
- a write that fails stops the writer: what was queued after it is dropped (the folder keeps its
  last complete checkpoint and the files written before it), and the error is raised in the trainer's
  thread by the next event or by :meth:`wait`, so it ends the job as it did when written inline;
- at most ``MAX_PENDING_CHECKPOINTS`` checkpoints wait to be written: a trainer faster than its disk
  waits for the writer rather than holding ever more copies of the networks in memory;
- the writer thread runs at a lower CPU priority (nice +``WRITER_NICENESS``): on a busy machine with
  few cores it takes the time training leaves rather than slowing the trainer's torch threads;
- a listener's ``prepare()`` runs first on the writer thread, as the job starts: the folder's
  recorder compiles the simtrace renderer there (numba: 7-9 s on the busy 2-core host with a cold
  cache, as on a fresh GPU machine), while the first iteration collects.
"""

from __future__ import annotations

import os
import queue
import threading
from typing import Sequence

MAX_PENDING_CHECKPOINTS = 3
_STOP = object()


class BackgroundListeners:
    """Runs ``listeners``' ``on_episodes``, ``on_checkpoint``, ``on_iteration`` and ``on_error`` on one
    background thread (named ``name``), in the order they came, after their ``prepare()``.

    A listener method that raises makes the writer stop; the exception is re-raised in the caller's
    thread by the next event, :meth:`wait` or :meth:`close`. Other events (``on_poses``,
    ``on_progress``) are not forwarded: those listeners write files, not live views."""

    def __init__(self, listeners: Sequence[object], name: str = "laplab-model-writer"):
        self.listeners = tuple(listeners)
        self.name = name
        self._tasks: queue.Queue = queue.Queue()
        self._checkpoint_slots = threading.BoundedSemaphore(MAX_PENDING_CHECKPOINTS)
        self._failure: BaseException | None = None
        self._reported = False
        self._thread: threading.Thread | None = None
        self._closed = False
        if any(getattr(listener, "prepare", None) for listener in self.listeners):
            self._submit("prepare", None)  # e.g. compiling the simtrace renderer while iteration 1 runs

    # -- the trainer's side ----------------------------------------------------------------------

    def on_episodes(self, payload) -> None:
        self._submit("on_episodes", payload)

    def on_checkpoint(self, payload) -> None:
        self._submit("on_checkpoint", payload)

    def on_iteration(self, payload) -> None:
        self._submit("on_iteration", payload)

    def on_error(self, payload) -> None:
        self._submit("on_error", payload)

    def wait(self) -> None:
        """Return once every event handed over is written; raise the failure of a write (once)."""
        if self._thread is not None:
            self._tasks.join()
        self._raise_failure()

    def close(self) -> None:
        """:meth:`wait`, then end the thread (later events are written in the caller's thread)."""
        try:
            self.wait()
        finally:
            self._closed = True
            if self._thread is not None:
                self._tasks.put(_STOP)
                self._thread.join()
                self._thread = None

    def _submit(self, event: str, payload) -> None:
        self._raise_failure()
        if self._closed:  # a late event (after the job ended): written here and now
            self._deliver(event, payload)
            return
        checkpoint = event == "on_checkpoint"
        if checkpoint:
            self._checkpoint_slots.acquire()  # blocks while MAX_PENDING_CHECKPOINTS wait to be written
            self._raise_failure(release=True)  # the writer may have failed while this thread waited
        if self._thread is None:
            self._thread = threading.Thread(target=self._work, name=self.name, daemon=True)
            self._thread.start()
        self._tasks.put((event, payload, checkpoint))

    def _raise_failure(self, release: bool = False) -> None:
        if self._failure is not None and not self._reported:
            if release:
                self._checkpoint_slots.release()
            self._reported = True  # raised once: the job ends with it (a second wait() does not repeat it)
            raise self._failure

    # -- the writer's side -----------------------------------------------------------------------

    def _deliver(self, event: str, payload) -> None:
        for listener in self.listeners:
            handler = getattr(listener, event, None)
            if handler is not None:
                handler() if event == "prepare" else handler(payload)

    def _work(self) -> None:
        _lower_priority()
        while True:
            task = self._tasks.get()
            try:
                if task is _STOP:
                    return
                event, payload, checkpoint = task
                try:
                    if self._failure is None:  # after a failure the queued writes are dropped
                        self._deliver(event, payload)
                except BaseException as exc:  # noqa: BLE001 - any failure ends the job, in its thread
                    self._failure = exc
                finally:
                    if checkpoint:
                        self._checkpoint_slots.release()
            finally:
                self._tasks.task_done()


WRITER_NICENESS = 10


def _lower_priority() -> None:
    """Lower the calling thread's CPU priority by ``WRITER_NICENESS`` (Linux: a thread's own nice value),
    so that on a busy machine with few cores the writer takes the CPU time training leaves (the
    trainer's torch threads wait for a descheduled sibling otherwise). Elsewhere it does nothing."""
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), os.getpriority(os.PRIO_PROCESS, 0) + WRITER_NICENESS)
    except (AttributeError, OSError):
        pass
