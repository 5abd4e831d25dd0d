"""The console's live event hub: per-model events and the cars' latest poses, as server-sent events.

The scheduler (:mod:`laplab.console.service`) publishes into the :class:`EventHub` as it tails the
running jobs' files; every open ``/events`` stream waits on its own ``asyncio.Event`` for news.
"""

from __future__ import annotations

import asyncio
import json
import threading
from collections import deque
from dataclasses import dataclass, field


@dataclass
class ModelStream:
    """Live state of one model for its event streams."""

    events: deque = field(default_factory=lambda: deque(maxlen=2000))  # (seq, kind, data, SSE text)
    seq: int = 0
    poses: dict | None = None
    poses_text: str = ""  # the poses as an SSE message, written once for every stream
    poses_seq: int = 0
    obstacles_text: str = ""  # the race's standing obstacles (boxes) as an SSE message, sent once per stream
    obstacles_seq: int = 0
    waiters: set = field(default_factory=set)  # asyncio.Event of each open stream, set on news


class EventHub:
    """Per-model events (iterations, status changes) and the latest poses, numbered for streams.
    An open stream waits on its own ``asyncio.Event``, set when its model has news (no polling)."""

    def __init__(self):
        self.streams: dict[str, ModelStream] = {}
        self.loop: asyncio.AbstractEventLoop | None = None  # the server's loop (set at start-up)
        self._loop_thread: int | None = None

    def attach(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop, self._loop_thread = loop, threading.get_ident()

    def stream(self, model: str) -> ModelStream:
        return self.streams.setdefault(model, ModelStream())

    def publish(self, model: str, kind: str, data: dict) -> None:
        stream = self.stream(model)
        stream.seq += 1
        stream.events.append((stream.seq, kind, data, sse_message(kind, data, stream.seq)))
        self._wake(stream)

    def set_poses(self, model: str, poses: dict) -> None:
        stream = self.stream(model)
        stream.poses, stream.poses_text = poses, sse_message("poses", poses)
        stream.poses_seq += 1
        self._wake(stream)

    def set_obstacles(self, model: str, obstacles: dict) -> None:
        """The race's standing obstacles (``{"seq", "boxes": [[x, y, yaw, half_length, half_width,
        kind], ...]}``): every open stream sends them once, a new one when it opens."""
        stream = self.stream(model)
        stream.obstacles_text = sse_message("obstacles", obstacles)
        stream.obstacles_seq += 1
        self._wake(stream)

    def _wake(self, stream: ModelStream) -> None:
        for waiter in list(stream.waiters):
            if self.loop is None or threading.get_ident() == self._loop_thread:
                waiter.set()
            else:  # published from a worker thread (a route running in the thread pool)
                self.loop.call_soon_threadsafe(waiter.set)


def sse_message(kind: str, data: dict, event_id: int | None = None) -> str:
    """One server-sent event: ``event: KIND`` and ``data: JSON`` (with ``id:`` when numbered)."""
    head = f"id: {event_id}\n" if event_id is not None else ""
    return f"{head}event: {kind}\ndata: {json.dumps(data)}\n\n"
