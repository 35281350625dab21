"""What a log holds: ``mavattitude info``, as a dict (for --json) and as text."""
from __future__ import annotations

import datetime
import os

import numpy as np

from .. import estimators as est
from ..core.policy import FlightFacts, RunOptions, decide
from ..declination import NO_DECLINATION
from ..flight import GRAVITY, Flight
from ..scoring.imucheck import accel_at_rest, accel_scale_warning, rate_not_meaningful, rate_warning
from ..readers import best_imu_source, imu_rate
from ..readers.attitudes import name_attitudes


def _rate(t: np.ndarray) -> float:
    return float(1.0 / np.median(np.diff(t))) if len(t) > 1 else 0.0


SEVERITIES = ("emergency", "alert", "critical", "error", "warning", "notice", "info", "debug")  # MAV_SEVERITY
WARNING = 4  # text lines at this severity or worse are listed one by one
SHOWN = 8  # modes and lines listed on the terminal (--json has them all)
WIDTH = 110


def _events(flight: Flight, end: float) -> dict:
    """The log's own account: its modes and armed spans, its text lines by severity and those
    at warning or worse (``Flight.modes``, ``arming``, ``messages``; None where it has none)."""
    modes = flight.modes.spans(end) if flight.modes is not None and len(flight.modes.t) else None
    armed = None
    if flight.arming is not None and len(flight.arming.t):
        armed = [(a, b) for a, b, value, _ in flight.arming.spans(end) if value == 1]
    texts = flight.messages if flight.messages is not None and len(flight.messages.t) else None
    return {
        "modes": None if modes is None else [{"start_s": round(a, 3), "end_s": round(b, 3), "number": v, "name": name}
                                             for a, b, v, name in modes],
        "armed": None if armed is None else [{"start_s": round(a, 3), "end_s": round(b, 3)} for a, b in armed],
        "messages": None if texts is None else {
            "by_severity": {SEVERITIES[v]: int(n) for v, n in zip(*np.unique(texts.value, return_counts=True))
                            if 0 <= v < len(SEVERITIES)},
            "warnings": [{"t_s": round(float(t), 3), "severity": SEVERITIES[v], "text": text}
                         for t, v, text in zip(texts.t, texts.value.tolist(), texts.label) if 0 <= v <= WARNING]},
    }


def summarize(flight: Flight) -> dict:
    start, end = flight.time_span
    duration = end - start
    best = best_imu_source(flight)
    imus = {}
    for key, s in flight.imu.items():
        norm = np.linalg.norm(s.accel, axis=1)
        g_reading, at_rest = accel_at_rest(s.t, s.gyro, s.accel)
        imus[key] = {
            "samples": len(s.t),
            "rate_hz": round(imu_rate(s), 2),
            "start_s": round(float(s.t[0]), 3),
            "end_s": round(float(s.t[-1]), 3),
            "accel_norm_ms2": {"mean": round(float(norm.mean()), 4), "std": round(float(norm.std()), 4),
                               "min": round(float(norm.min()), 4), "max": round(float(norm.max()), 4),
                               "median": round(float(np.median(norm)), 4)},
            # the accelerometer's reading of g: median |a| at rest (else over the whole series)
            "accel_g_reading": {"ms2": None if g_reading is None else round(g_reading, 4), "at_rest": at_rest,
                                "scale_error": None if g_reading is None else round(g_reading / GRAVITY - 1.0, 4)},
            "best": key == best,
        }
    sensors = {
        "imu": sorted(flight.imu),
        "magnetometer": sorted(flight.mag),
        "gps": flight.gps.source if flight.gps is not None else None,
        "barometer": flight.baro.source if flight.baro is not None else None,
        "attitude": flight.attitude.source if flight.attitude is not None else None,
        "ground_truth": flight.truth.source if flight.truth is not None else None,
    }
    rates = {}
    for kind, s in flight.all_series():
        rates[s.source if kind in ("imu", "mag") else f"{kind}:{s.source}"] = round(_rate(s.t), 2)
    warnings = list(flight.warnings)
    best_rate = imu_rate(flight.imu[best])
    if (low_rate := rate_warning(best_rate)) is not None:
        warnings.append(low_rate)
    reading = imus[best]["accel_g_reading"]
    scale = accel_scale_warning(reading["ms2"], reading["at_rest"], [est.create(name) for name in est.all_names()])
    if scale is not None:
        warnings.append(scale)
    declination = decide(RunOptions(()), FlightFacts.of(flight)).declination  # as replay takes it
    if flight.mag and not declination.known:
        warnings.append(NO_DECLINATION)
    return {
        "log": flight.path,
        "format": flight.format,
        "size_bytes": os.path.getsize(flight.path),
        "vehicle": flight.vehicle,
        "firmware": flight.firmware,
        "start_s": round(start, 3),
        "end_s": round(end, 3),
        "duration_s": round(duration, 3),
        "clock_segments": [{"start_s": round(a, 3), "end_s": round(b, 3)} for a, b in flight.segments],
        "segment_used": flight.segment_index,
        "sensors": sensors,
        "imu_sources": imus,
        "best_imu": best,
        "scores": {"meaningful": rate_not_meaningful(best_rate) is None, "why": rate_not_meaningful(best_rate)},
        "sample_rates_hz": rates,
        "attitude_streams": [{"stream": n.key, "algorithm": n.algorithm, "primary": n.primary,
                              "samples": len(flight.attitudes[n.key].t),
                              "rate_hz": round(_rate(flight.attitudes[n.key].t), 2), "named_by": n.evidence,
                              "equals": {k: round(v, 3) for k, v in n.equals.items()}}
                             for n in name_attitudes(flight)],
        "message_counts": dict(sorted(flight.message_counts.items())),
        "message_rates_hz": {k: round(v / duration, 3) if duration > 0 else None
                             for k, v in sorted(flight.message_counts.items())},
        "parameters": len(flight.params),
        "date_utc": (datetime.datetime.fromtimestamp(flight.utc_s, datetime.timezone.utc).isoformat(timespec="seconds")
                     if flight.utc_s is not None else None),
        "declination_deg": round(declination.deg, 3) if declination.known else None,
        "declination_source": declination.source,
        "events": _events(flight, end),
        "notes": list(flight.notes),
        "warnings": warnings,
    }


def render(info: dict) -> str:
    lines = [f"{info['log']}  ({info['format']}, {info['size_bytes'] / 1e6:.1f} MB)"]
    lines.append(f"  vehicle   {info['vehicle'] or 'unknown'}   firmware {info['firmware'] or 'unknown'}")
    lines.append(f"  time      {info['start_s']:.1f} - {info['end_s']:.1f} s on the autopilot clock "
                 f"({info['duration_s']:.1f} s)")
    if len(info["clock_segments"]) > 1:
        lines.append(f"  segments  {len(info['clock_segments'])} (autopilot rebooted); using #{info['segment_used']}")
    s = info["sensors"]
    lines.append("  sensors   " + ", ".join(f"{k}: {v if v else '-'}" for k, v in (
        ("magnetometer", ", ".join(s["magnetometer"])), ("gps", s["gps"]), ("baro", s["barometer"]),
        ("attitude", s["attitude"]), ("truth", s["ground_truth"]))))
    dec = info["declination_deg"]
    lines.append(f"  date      {info['date_utc'] or 'unknown (no GPS or system time)'}")
    lines.append(f"  declination {'%.2f°' % dec if dec is not None else 'unknown'} ({info['declination_source']})")
    lines.append("  IMU sources (* = used by default):")
    for key, imu in info["imu_sources"].items():
        a = imu["accel_norm_ms2"]
        lines.append(f"   {'*' if imu['best'] else ' '} {key:16s} {imu['samples']:8d} samples  {imu['rate_hz']:7.1f} Hz"
                     f"   |accel| mean {a['mean']:.3f} ± {a['std']:.3f} m/s² (g = {GRAVITY})")
        g = imu["accel_g_reading"]
        if g["ms2"] is not None:
            lines.append(f"{'':30s}reads g as {g['ms2']:.3f} m/s² ({100 * g['scale_error']:+.1f} %) "
                         + ("at rest" if g["at_rest"] else "over the whole log (no rest span)"))
    if info["attitude_streams"]:
        lines.append("  autopilot attitudes (* = primary, the 'autopilot' reference; --reference NAME takes any):")
    for a in info["attitude_streams"]:
        same = [f"{k} {100 * v:.0f} %" for k, v in a["equals"].items() if v >= 0.05]
        why = a["named_by"] + ("; equals " + ", ".join(same) if same else "")
        lines.append(f"   {'*' if a['primary'] else ' '} {a['stream']:22s} {a['algorithm']:16s} {a['samples']:8d} "
                     f"samples  {a['rate_hz']:7.1f} Hz   ({why})")
    lines += _render_events(info["events"])
    for note in info["notes"]:
        lines.append(f"  note: {note}")
    for warning in info["warnings"]:
        lines.append(f"  warning: {warning}")
    return "\n".join(lines)


def _render_events(events: dict) -> list[str]:
    def listed(head: str, items: list[str]) -> list[str]:
        shown = items[:SHOWN] + ([f"... {len(items) - SHOWN} more (--json lists them all)"] if len(items) > SHOWN else [])
        lines = [f"  {head:10s}{shown[0]}"]
        for item in shown[1:]:  # wrapped between items, never inside one
            if len(lines[-1]) + len(item) + 2 > WIDTH:
                lines[-1] += ","
                lines.append(" " * 12 + item)
            else:
                lines[-1] += ", " + item
        return lines

    lines = []
    if (modes := events["modes"]) is not None:
        lines += listed("modes", [f"{m['name'] or m['number']} {m['start_s']:.1f}-{m['end_s']:.1f} s" for m in modes])
    if (armed := events["armed"]) is not None:
        lines += listed("armed", [f"{a['start_s']:.1f}-{a['end_s']:.1f} s" for a in armed] or ["never"])
    if (texts := events["messages"]) is not None:
        counts = ", ".join(f"{n} {name}" for name, n in texts["by_severity"].items())
        lines.append(f"  {'messages':10s}{sum(texts['by_severity'].values())} ({counts})")
        warnings = texts["warnings"]
        lines += [f"{'':12s}{w['t_s']:8.1f} s  {w['severity']:9s} {w['text']}" for w in warnings[:SHOWN]]
        if len(warnings) > SHOWN:
            lines.append(f"{'':12s}... {len(warnings) - SHOWN} more (--json lists them all)")
    return lines
