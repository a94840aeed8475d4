"""Thread helpers of the reconstruction: an iterator prefetched in a background thread."""

from __future__ import annotations

import queue
import threading


def prefetch(iterable, depth: int = 2):
    """Iterate in a background thread, at most ``depth`` items ahead (video decoding overlaps the work).

    An error raised by the producer is raised in the consumer, at the item where it happened.
    """
    q: queue.Queue = queue.Queue(maxsize=depth)
    done = object()
    stop = threading.Event()

    def run():
        try:
            for item in iterable:
                if stop.is_set():
                    return
                q.put((item, None))
            q.put((done, None))
        except BaseException as err:  # handed to the consumer, raised there
            q.put((done, err))

    t = threading.Thread(target=run, name="decode", daemon=True)
    t.start()
    try:
        while True:
            item, err = q.get()
            if err is not None:
                raise err
            if item is done:
                return
            yield item
    finally:
        stop.set()
        while t.is_alive():  # unblock a producer waiting on a full queue
            try:
                q.get_nowait()
            except queue.Empty:
                t.join(0.05)
