"""A call repeated in a thread while a ``with`` block runs: a joint-state feed for the tests."""
import contextlib
import threading
from typing import Callable


@contextlib.contextmanager
def repeating(call: Callable[[], None], rate: float):
    """Call ``call()`` at about ``rate`` Hz in a daemon thread until the block ends."""
    stop = threading.Event()

    def loop():
        while not stop.is_set():
            call()
            stop.wait(1.0 / rate)

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(5)
