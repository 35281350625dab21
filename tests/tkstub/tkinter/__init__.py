"""A stand-in for tkinter, so pymavlink's mavplayback.py (a Tk program) runs headless in the
tests: its widgets do nothing, and ``Tk.after``/``mainloop`` are a real timer loop, which is
all mavplayback uses Tk for (pacing the replay by the log's timestamps).

The playback speed (mavplayback reads it from a Spinbox) comes from MAVPLAYBACK_SPEED (default
1); the loop ends after MAVPLAYBACK_SECONDS of wall time (default: never).
"""
import heapq
import itertools
import os
import time

TOP = LEFT = RIGHT = BOTTOM = HORIZONTAL = "stub"


class _Widget:
    def __init__(self, *args, **kwargs):
        self._value = kwargs.get("from_", 0)

    def pack(self, *args, **kwargs):
        pass

    def configure(self, *args, **kwargs):
        pass

    def set(self, value):
        self._value = value

    def get(self):
        return self._value

    def delete(self, *args):
        pass

    def insert(self, *args):
        pass

    def quit(self):
        pass


class Frame(_Widget):
    pass


class Label(_Widget):
    pass


class Button(_Widget):
    pass


class Scale(_Widget):
    pass


class Spinbox(_Widget):
    def get(self):
        return os.environ.get("MAVPLAYBACK_SPEED", "1")


class PhotoImage(_Widget):
    pass


class Tk(_Widget):
    def __init__(self, *args, **kwargs):
        super().__init__()
        self._timers = []
        self._order = itertools.count()
        self._quit = False

    def after(self, ms, callback, *args):
        heapq.heappush(self._timers, (time.monotonic() + ms / 1000.0, next(self._order), callback, args))

    def quit(self):  # noqa: F811 (the window's quit ends the loop)
        self._quit = True

    def mainloop(self):
        seconds = os.environ.get("MAVPLAYBACK_SECONDS")
        end = time.monotonic() + float(seconds) if seconds else float("inf")
        while self._timers and not self._quit and time.monotonic() < end:
            due, _, callback, args = heapq.heappop(self._timers)
            wait = due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            callback(*args)
