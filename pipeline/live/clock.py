"""The live twin's simulated clock: simulated time = real time x speed from the last
change (a pause, a resume, a new speed, a seek), the study's accelerated virtual time.
Pure: the wall clock is handed in (time.monotonic by default), so tests drive it."""

from __future__ import annotations

import datetime as dt
import math
import time
from typing import Callable

SPEED_MAX = 1.0e6  # a day of simulated time in 0.09 s of real time: faster is a typo


class SimClock:
    def __init__(self, start: dt.datetime, speed: float = 1.0, wall: Callable[[], float] = time.monotonic):
        if start.tzinfo is None:
            raise ValueError("the clock's start needs a UTC offset")
        self._wall = wall
        self._origin = start  # the simulated instant at _wall0
        self._wall0 = wall()
        self.speed = check_speed(speed)
        self.paused = False

    def now(self) -> dt.datetime:
        """The simulated instant (aware, in the zone of the start or of the last seek)."""
        if self.paused:
            return self._origin
        return self._origin + dt.timedelta(seconds=(self._wall() - self._wall0) * self.speed)

    def wall_until(self, instant: dt.datetime) -> float:
        """Real seconds until the clock shows `instant` (inf while paused; 0 if past)."""
        if self.paused:
            return math.inf
        return max(0.0, (instant - self.now()).total_seconds() / self.speed)

    def _rebase(self) -> None:
        self._origin, self._wall0 = self.now(), self._wall()

    def pause(self) -> None:
        self._rebase()
        self.paused = True

    def resume(self) -> None:
        if self.paused:
            self._wall0 = self._wall()
            self.paused = False

    def set_speed(self, speed: float) -> None:
        speed = check_speed(speed)
        self._rebase()
        self.speed = speed

    def seek(self, instant: dt.datetime) -> None:
        if instant.tzinfo is None:
            raise ValueError("a seek needs an instant with a UTC offset")
        self._origin, self._wall0 = instant, self._wall()

    def state(self) -> dict:
        return {"sim_time": self.now().isoformat(), "speed": self.speed, "paused": self.paused}


def check_speed(speed) -> float:
    if isinstance(speed, bool) or not isinstance(speed, (int, float)) or not 0.0 < speed <= SPEED_MAX:
        raise ValueError(f"speed {speed!r} is not in (0, {SPEED_MAX:g}]")
    return float(speed)


def parse_instant(text: str, zone: dt.tzinfo | None) -> dt.datetime:
    """An ISO 8601 date-time; without a UTC offset it is a wall-clock time on the site's
    clock (`zone`). ValueError names what is wrong."""
    from .. import config

    try:
        when = dt.datetime.fromisoformat(str(text).replace("Z", "+00:00"))
    except ValueError:
        raise ValueError(f"{text!r} is not an ISO 8601 date-time") from None
    if when.tzinfo is None:
        if zone is None:
            raise ValueError(f"{text!r} has no UTC offset and the site has no time zone")
        when = config.local_time(when, zone)
    return when
