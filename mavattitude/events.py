"""What happened during a replay or a live session, on the autopilot clock, for the
terminal, the JSON and the Rerun view."""
from __future__ import annotations

from dataclasses import dataclass

FIRST_TIMES = 3  # times a terminal line that stands for many events lists


@dataclass
class Event:
    t: float  # s, autopilot clock
    level: str  # "info", "warn"
    text: str
    # Events of one kind share a terminal line ("IMU gap over 2 s, estimators re-initialised"):
    # set where one warning can recur many times; "" groups by the text alone
    kind: str = ""

    def as_dict(self) -> dict:
        return {"t_s": round(self.t, 3), "level": self.level, "kind": self.kind or None, "text": self.text}


def grouped_lines(events, level: str = "warn") -> list[str]:
    """One line per kind of event at ``level``, in the order of each kind's first event: the
    event's own text when there is one, else the kind, how many and the first few times
    ("cpf-ekf: watchdog reset ...: 27 times, at 121.2, 135.2, 148.2, … s"). A log's hundred
    resets would otherwise scroll everything else away; the JSON and the view keep each one."""
    groups: dict[str, list[Event]] = {}
    for event in sorted(events, key=lambda e: e.t):
        if event.level == level:
            groups.setdefault(event.kind or event.text, []).append(event)
    lines = []
    for key, group in groups.items():
        if len(group) == 1:
            lines.append(group[0].text)
            continue
        times = ", ".join(f"{e.t:.1f}" for e in group[:FIRST_TIMES]) + (", …" if len(group) > FIRST_TIMES else "")
        lines.append(f"{key}: {len(group):,} times, at {times} s")
    return lines
