"""What happened during a replay or a live session, on the autopilot clock, for the
terminal, the JSON and the Rerun view."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Event:
    t: float  # s, autopilot clock
    level: str  # "info", "warn"
    text: str
