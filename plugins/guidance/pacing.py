"""Pacing a stream of timed samples on the wall clock."""

from __future__ import annotations

import time


class Pacer:
    """Waits until ``t / speed`` seconds after the first call; ``speed <= 0`` never waits."""

    def __init__(self, speed: float) -> None:
        self.speed = speed
        self.origin: float | None = None

    def wait(self, t: float) -> None:
        if self.speed <= 0:
            return
        now = time.monotonic()
        if self.origin is None:
            self.origin = now - t / self.speed
        delay = self.origin + t / self.speed - now
        if delay > 0:
            time.sleep(delay)
