"""Server-sent events: worker threads publish, every connected page receives.

:meth:`EventBus.publish` may be called from any thread (the status poller, campaign cycles,
request handlers); each subscriber is an :class:`asyncio.Queue` on the server's event loop,
fed with ``loop.call_soon_threadsafe``. A slow client whose queue is full loses its oldest
events rather than holding up the plant (the page re-reads the JSON state on reconnect).
"""

from __future__ import annotations

import asyncio
import math
import threading
import time
from collections.abc import AsyncIterator
from typing import Any

import numpy as np

from controller.io.json_files import dumps_json

QUEUE_SIZE = 500
KEEPALIVE_S = 15.0


class EventBus:
    """Fan-out of ``(event, data)`` pairs to the subscribed SSE streams."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._subs: list[tuple[asyncio.AbstractEventLoop, asyncio.Queue]] = []
        self._closed = False

    def publish(self, event: str, data: dict) -> None:
        """Send ``data`` (JSON-able; ``t`` = wall time of publication, s since the epoch) to
        every subscriber as SSE event ``event``."""
        payload = dumps_json(plain({**data, "t": time.time()}))
        with self._lock:
            subs = list(self._subs)
        for loop, q in subs:
            try:
                loop.call_soon_threadsafe(_put, q, (event, payload))
            except RuntimeError:  # the loop is closed: the server is going down
                pass

    def close(self) -> None:
        """End every stream (server shutdown)."""
        with self._lock:
            self._closed = True
            subs = list(self._subs)
        for loop, q in subs:
            try:
                loop.call_soon_threadsafe(_put, q, None)
            except RuntimeError:
                pass

    async def stream(self) -> AsyncIterator[str]:
        """One client's SSE stream (text frames), until the bus closes or the client leaves."""
        loop = asyncio.get_running_loop()
        q: asyncio.Queue = asyncio.Queue(QUEUE_SIZE)
        entry = (loop, q)
        with self._lock:
            if self._closed:
                return
            self._subs.append(entry)
        try:
            yield "retry: 1000\n\n"
            while True:
                try:
                    item = await asyncio.wait_for(q.get(), KEEPALIVE_S)
                except TimeoutError:
                    yield ": keepalive\n\n"
                    continue
                if item is None:
                    return
                event, payload = item
                yield f"event: {event}\ndata: {payload}\n\n"
        finally:
            with self._lock:
                if entry in self._subs:
                    self._subs.remove(entry)


def _put(q: asyncio.Queue, item) -> None:
    if item is not None and q.full():
        q.get_nowait()  # drop the oldest event of a client that does not keep up
    q.put_nowait(item)


def plain(value: Any) -> Any:
    """``value`` with numpy scalars/arrays and tuples as JSON types, non-finite floats as None."""
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return plain(value.tolist())
    if isinstance(value, np.generic):
        return plain(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
