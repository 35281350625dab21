"""Estimation on a live link: the replay's estimators, stepped as the vehicle's samples arrive.

``LiveEstimation`` takes the vehicle's decoded MAVLink messages (``add``) and, on each
``step``, runs every estimator over the IMU samples that arrived since the last step, with the
same inputs replay builds from a log (``pipeline``): the magnetometer held on the IMU clock,
the ground/air phase, GPS and baro aiding. Knows nothing of sockets; the session feeds it.

On the autopilot's clock, per clock segment (a reboot starts a new one):
- samples of a series not newer than its last one (repeats, reordering) are dropped, as
  corrupt ones are (readers' plausibility limits), and so is a GPS or baro sample older than
  the clock by more than ``REBOOT_JUMP_S`` (a GPS that lost its fix repeats the time of its
  last one);
- the clock is the IMU's and the attitude's: a reboot is the clock going back by more than
  ``REBOOT_JUMP_S`` on two samples in a row (one such sample is a corrupt record, dropped),
  and one sample ``FORWARD_JUMP_S`` ahead of the clock counts only once the next confirms it;
- a compass whose unit is off by a power of 1000 (ArduPilot 4.7's HIGHRES_IMU) is rescaled,
  judged on its first ``MAG_SCALE_SAMPLES``, as the reader does;
- the estimators start once ``ALIGN_S`` of IMU data is in (and, when a compass is there and
  the session asked for COMPASS_DEC, once it has arrived, or ``DECLINATION_WAIT_S`` more have
  passed): the alignment (initial attitude, gyro bias over a still period) sees that much,
  then the estimators catch up over it;
- an IMU gap longer than ``pipeline.REINIT_GAP_S`` re-initialises them, as in replay, and so
  does a reboot (the clock going back more than ``REBOOT_JUMP_S``): events say so.

Differences from replay, all from seeing only the past: the alignment's still period is at
most ``ALIGN_S`` long; the phase is judged causally (``phase.PhaseTracker``); the GPS origin is
the first good fix and the baro zero the first samples' median; a GPS or baro sample that
arrives after the IMU samples of its time were processed is fused at the next one (if at most
``aiding.MAX_LATENCY_S`` late).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from .. import aiding as aid
from .. import estimators as est
from .. import quaternion as quat
from ..flight import AttitudeSeries, BaroSeries, GpsSeries, MagSeries
from ..growing import Growing
from ..metrics import AXES, Comparison, circular_mean_deg, compare
from ..phase import PhaseTracker, pressure_height
from ..pipeline import LOW_IMU_RATE_HZ, REINIT_GAP_S, Event, mag_on_imu_clock
from ..readers import IMU_LIMITS, MAG_LIMITS, earth_field_power, pick_imu, pick_mag
from ..readers.collect import FORWARD_JUMP_S, REBOOT_JUMP_S
from ..readers.tlog import MessageDecoder

ALIGN_S = 3.0  # s of IMU data before the estimators start
ALIGN_MIN_SAMPLES = 10
DECLINATION_WAIT_S = 2.0  # s more of IMU data to wait for a COMPASS_DEC that was asked for
MAG_SCALE_SAMPLES = 5  # compass samples that decide its unit
CLOCK_KINDS = ("imu", "att_euler", "att_quat", "truth_euler")  # the messages that carry the clock
REFERENCE_KINDS = {"att_euler": "autopilot", "att_quat": "autopilot_q", "truth_euler": "truth"}


@dataclass
class Chunk:
    """What one ``step`` produced: new estimates at the IMU times ``t``."""
    t: np.ndarray
    q: dict[str, np.ndarray]  # estimator -> (N, 4)
    diagnostics: dict[str, dict[str, np.ndarray]]  # estimator -> key -> (N,)
    in_air: np.ndarray


class _Segment:
    """Everything of one clock segment (between reboots)."""

    def __init__(self, index: int):
        self.index = index
        self.clock_max = -math.inf
        self.mag_scale: dict[str, float] = {}  # source -> factor its samples are multiplied by
        self.mag_pending: dict[str, list] = {}  # source -> first samples, until the unit is judged
        self.imu: dict[str, Growing] = {}  # source -> rows t, gyro (3), accel (3), arrival (monotonic s)
        self.mag: dict[str, Growing] = {}  # source -> rows t, field (3) T
        self.gps = Growing(10)  # t, lat, lon, alt, vn, ve, vd, fix, sats, h_acc
        self.baro = Growing(3)  # t, pressure Pa, alt
        self.att: dict[str, Growing] = {}  # "autopilot", "autopilot_q", "truth" -> rows t, q (4)
        self.imu_key: str | None = None
        self.mag_key: str | None = None
        self.done = 0  # rows of the IMU processed
        self.running = False  # estimators initialised for the current run
        self.est: dict[str, Growing] = {}  # estimator -> rows t, q (4)
        self.restarts: list[float] = []
        self.gps_done = 0
        self.baro_done = 0
        self.height_done = 0
        self.origin = None
        self.baro_zero = None
        self.phase: PhaseTracker | None = None
        self.alignment: est.Alignment | None = None
        self.yaw_offset: dict[str, float] = {}  # no-heading estimators: yaw offset of the current run


class LiveEstimation:
    """Estimators ``names`` (with ``params``: name -> dataclass) on a live vehicle's data.

    ``declination_deg``: None takes the vehicle's COMPASS_DEC when it has arrived by the
    start, else 0 with a warning. ``reference``: "autopilot" or "truth" (SIMSTATE).
    ``record_latency``: keep (time_usec, monotonic s when estimated) per IMU sample."""

    def __init__(self, names: list[str], params: dict | None = None, declination_deg: float | None = None,
                 use_mag: bool = True, imu_source: str | None = None, reference: str = "autopilot",
                 warmup_s: float = 10.0, record_latency: bool = False, expect_declination: bool = False):
        self.names = list(names)
        self.params = params or {}
        self.declination_deg = declination_deg
        self.declination = 0.0
        self.use_mag = use_mag
        self.imu_choice = imu_source
        self.reference = reference
        self.warmup_s = warmup_s
        self.decoder = MessageDecoder()
        self.estimators: list[est.Estimator] = []
        self.has_heading: dict[str, bool] = {}
        self.events: list[Event] = []
        self.segments: list[_Segment] = [_Segment(0)]
        self.dropped = 0  # samples not newer than their series' last, or implausible
        self.samples = 0  # IMU samples estimated
        self.record_latency = record_latency
        self.latency: list[tuple[float, float, float]] = []  # (t autopilot s, arrival, estimated) monotonic s
        self.expect_declination = expect_declination  # COMPASS_DEC was asked for: wait a little for it
        self._now = 0.0
        self._back: tuple[float, tuple] | None = None  # a clock sample far behind, until confirmed
        self._ahead: tuple | None = None  # a clock sample far ahead, until confirmed
        self._warned_imu = False

    # ------------------------------------------------------------ input

    @property
    def seg(self) -> _Segment:
        return self.segments[-1]

    def add(self, msg, now: float | None = None) -> None:
        """A message from the vehicle (``now``: its arrival, monotonic s)."""
        self._now = time.monotonic() if now is None else now
        self.decoder.decode(msg, self._add)

    def _add(self, kind: str, key: str, t: float, row: tuple) -> None:
        if not math.isfinite(t):
            return
        seg = self.seg
        if kind not in CLOCK_KINDS:
            if t < seg.clock_max - REBOOT_JUMP_S:  # stale (a GPS without a fix repeats its last time)
                self.dropped += 1
                return
        elif t < seg.clock_max - REBOOT_JUMP_S:
            back, self._back = self._back, (t, (kind, key, t, row))
            if back is None or abs(t - back[0]) > REBOOT_JUMP_S:
                return  # one sample far back: a corrupt record, unless the next agrees
            self._back = None
            self._event(t, "warn", f"the autopilot clock went back from {seg.clock_max:.1f} s to {t:.1f} s "
                                   "(a reboot): estimators re-initialised")
            self.segments.append(_Segment(len(self.segments)))
            seg = self.seg
            seg.clock_max = back[0]
            self._add(*back[1])
        elif math.isfinite(seg.clock_max) and t > seg.clock_max + FORWARD_JUMP_S:
            ahead, self._ahead = self._ahead, (kind, key, t, row)
            if ahead is None or abs(t - ahead[2]) > FORWARD_JUMP_S:
                return  # one sample far ahead: held until the next says whether the clock jumped
            self._ahead = None
            seg.clock_max = ahead[2]
            self._add(*ahead)
        else:
            self._back = self._ahead = None
        if kind in CLOCK_KINDS:
            seg.clock_max = max(seg.clock_max, t)
        if kind == "imu":
            if not any(row) or not _within(row, IMU_LIMITS):
                self.dropped += 1
                return
            self._append(seg.imu, key, 8, t, (*row, self._now))
        elif kind == "mag":
            if not any(row) or not all(math.isfinite(v) for v in row):
                return
            scale = seg.mag_scale.get(key)
            if scale is None:  # judge the unit on the first few samples, then let them in
                pending = seg.mag_pending.setdefault(key, [])
                pending.append((t, row))
                if len(pending) < MAG_SCALE_SAMPLES:
                    return
                power, strength = earth_field_power(np.array([r for _, r in pending]))
                scale = seg.mag_scale[key] = 10.0 ** (-3 * power)
                if power:
                    self._event(t, "info", f"{key}: magnetometer strength {strength * 1e4:.4g} G is implausible; "
                                           f"rescaled by 1e{-3 * power}")
                del seg.mag_pending[key]
                for tp, rp in pending[:-1]:
                    self._add_mag(seg, key, tp, rp, scale)
            self._add_mag(seg, key, t, row, scale)
        elif kind == "gps":
            self._append_one(seg.gps, t, row)
        elif kind == "baro":
            self._append_one(seg.baro, t, row)
        elif kind in REFERENCE_KINDS:
            if kind.endswith("euler"):
                if not all(math.isfinite(v) and abs(v) < 10.0 for v in row):
                    return
                q = quat.from_euler(row[0], row[1], row[2])
            else:
                q = np.asarray(row, dtype=float)
                if not np.isfinite(q).all() or np.linalg.norm(q) < 0.5:
                    return
                q = q / np.linalg.norm(q)
            self._append(seg.att, REFERENCE_KINDS[kind], 5, t, tuple(np.ravel(q)))

    def _add_mag(self, seg: _Segment, key: str, t: float, row: tuple, scale: float) -> None:
        row = tuple(v * scale for v in row)
        if _within(row, MAG_LIMITS):
            self._append(seg.mag, key, 4, t, row)

    def _append(self, stores: dict, key: str, width: int, t: float, row) -> None:
        store = stores.get(key)
        if store is None:
            store = stores[key] = Growing(width)
        self._append_one(store, t, row)

    def _append_one(self, store: Growing, t: float, row) -> None:
        last = store.last
        if last is not None and t <= last[0]:
            self.dropped += 1
            return
        store.append((t, *row))

    # ------------------------------------------------------------ stepping

    def step(self) -> Chunk | None:
        """Run the estimators over the IMU samples that arrived since the last step."""
        seg = self.seg
        if seg.imu_key is None and not self._choose_sources(seg):
            return None
        imu = seg.imu[seg.imu_key]
        chunks = []
        while seg.done < imu.n:
            t = imu.column(0)
            a = seg.done
            if seg.running and a > 0 and t[a] - t[a - 1] > REINIT_GAP_S:
                seg.running = False
                seg.restarts.append(float(t[a]))
                self._event(float(t[a]), "warn", f"IMU gap of {t[a] - t[a - 1]:.1f} s: estimators re-initialised")
            if not seg.running and not self._start_run(seg, a):
                break
            d = np.diff(t[a:imu.n])
            gaps = np.flatnonzero(d > REINIT_GAP_S)
            b = a + int(gaps[0]) + 1 if len(gaps) else imu.n
            chunks.append(self._run(seg, a, b))
            seg.done = b
        if not chunks:
            return None
        if len(chunks) == 1:
            return chunks[0]
        return Chunk(np.concatenate([c.t for c in chunks]),
                     {n: np.vstack([c.q[n] for c in chunks]) for n in self.names},
                     {n: {k: np.concatenate([c.diagnostics[n][k] for c in chunks])
                          for k in chunks[0].diagnostics[n]} for n in self.names},
                     np.concatenate([c.in_air for c in chunks]))

    def _choose_sources(self, seg: _Segment) -> bool:
        if not seg.imu:
            return False
        first = min(s.column(0)[0] for s in seg.imu.values())
        span = max(s.column(0)[-1] for s in seg.imu.values()) - first
        if span < ALIGN_S:
            return False  # let every source (and the compass, and COMPASS_DEC) show up first
        if (self.expect_declination and self.declination_deg is None and seg.mag and self.use_mag
                and "COMPASS_DEC" not in self.decoder.params and span < ALIGN_S + DECLINATION_WAIT_S):
            return False
        if self.imu_choice is not None:
            if self.imu_choice not in seg.imu:
                if not self._warned_imu:
                    self._warned_imu = True
                    self._event(first + span, "warn", f"no {self.imu_choice} samples arrive; the link carries "
                                                      f"{', '.join(sorted(seg.imu))} (--imu)")
                return False
            key = self.imu_choice
        else:
            key = pick_imu({k: s.n for k, s in seg.imu.items()})
        seg.imu_key = key
        seg.mag_key = pick_mag(list(seg.mag), key) if self.use_mag else None
        if not self.estimators:
            self._create_estimators(seg)
        return True

    def _create_estimators(self, seg: _Segment) -> None:
        if self.declination_deg is not None:
            self.declination, source = math.radians(self.declination_deg), "--declination"
        elif "COMPASS_DEC" in self.decoder.params:
            self.declination, source = float(self.decoder.params["COMPASS_DEC"]), "vehicle parameter COMPASS_DEC"
        else:
            self.declination, source = 0.0, None
        t0 = float(seg.imu[seg.imu_key].column(0)[0])
        rate = _rate(seg.imu[seg.imu_key].column(0))
        self._event(t0, "info", f"IMU source {seg.imu_key} at {rate:.1f} Hz, magnetometer {seg.mag_key or 'none'}; "
                                f"declination {math.degrees(self.declination):.2f}° ({source or 'none'})")
        if rate < LOW_IMU_RATE_HZ:
            self._event(t0, "warn", f"low IMU rate: {rate:.1f} Hz (below {LOW_IMU_RATE_HZ:.0f} Hz): "
                                    "gyro integration is coarse and estimates will lag")
        if seg.mag_key and source is None:
            self._event(t0, "warn", "no COMPASS_DEC from the vehicle and no --declination: using 0°; "
                                    "yaw compares magnetic with true heading")
        self.estimators = [est.create(n, self.params.get(n), self.declination) for n in self.names]

    def _start_run(self, seg: _Segment, a: int) -> bool:
        imu = seg.imu[seg.imu_key]
        rows = imu.view()[a:]
        if len(rows) < ALIGN_MIN_SAMPLES or rows[-1, 0] - rows[0, 0] < ALIGN_S:
            return False
        mag = self._mag_held(seg, rows[:, 0])
        alignment = est.align(rows[:, 0], rows[:, 1:4], rows[:, 4:7], mag, self.declination)
        if alignment.still_span is None and seg.alignment is not None:
            alignment.gyro_bias = seg.alignment.gyro_bias  # no new still period: keep the first
        first = seg.alignment is None
        if first:
            seg.alignment = alignment
            if alignment.still_span:
                s0, s1 = alignment.still_span
                bias = np.degrees(alignment.gyro_bias)
                self._event(s1, "info", f"still {s0:.1f}-{s1:.1f} s: gyro bias "
                                        f"[{bias[0]:.3f}, {bias[1]:.3f}, {bias[2]:.3f}] °/s")
            else:
                self._event(float(rows[0, 0]), "warn", "no initial still period: gyro bias starts at 0")
        for e in self.estimators:
            q0 = alignment.q0
            previous = seg.est.get(e.name)
            if not alignment.heading_from_mag and previous is not None and previous.n:
                # no heading reference: carry the yaw over the gap rather than restart it at 0
                roll, pitch, _ = quat.to_euler(q0)
                q0 = quat.from_euler(roll, pitch, quat.to_euler(previous.last[1:5])[2])
            e.initialize(q0, alignment.gyro_bias)
            self.has_heading[e.name] = e.has_heading_reference(seg.mag_key is not None)
        seg.yaw_offset.clear()
        seg.running = True
        return True

    def _run(self, seg: _Segment, a: int, b: int) -> Chunk:
        rows = seg.imu[seg.imu_key].view()[a:b]
        t = np.ascontiguousarray(rows[:, 0])
        gyro, accel = rows[:, 1:4], rows[:, 4:7]
        mag = self._mag_held(seg, t)
        in_air = self._in_air(seg, t)
        aiding = self._aiding(seg, t) if any(e.uses_aiding for e in self.estimators) else None
        out, diagnostics = {}, {}
        for e in self.estimators:
            extra = {"aiding": aiding} if e.uses_aiding else {}
            q = e.update(t, gyro, accel, mag, in_air, **extra)
            out[e.name] = q
            diagnostics[e.name] = dict(e.diagnostics)
            store = seg.est.get(e.name)
            if store is None:
                store = seg.est[e.name] = Growing(5)
            store.extend(np.column_stack([t, q]))
            resets = diagnostics[e.name].get("reset")
            if resets is not None:
                for tr in t[np.asarray(resets) == 1.0]:
                    self._event(float(tr), "warn", f"{e.name}: watchdog reset (EKF attitude too far from its "
                                                   "complementary filter): restarted from it")
        done = time.monotonic()
        if self.record_latency:
            self.latency.extend(zip(t.tolist(), rows[:, 7].tolist(), [done] * len(t)))
        self.samples += len(t)
        return Chunk(t, out, diagnostics, in_air)

    def _mag_held(self, seg: _Segment, t: np.ndarray) -> np.ndarray | None:
        """The latest compass sample at each IMU time, NaN where stale (``mag_on_imu_clock``)."""
        if seg.mag_key is None or seg.mag_key not in seg.mag:
            return None
        m = seg.mag[seg.mag_key].view()
        a = max(int(np.searchsorted(m[:, 0], t[0], side="right")) - 1, 0)
        b = int(np.searchsorted(m[:, 0], t[-1], side="right"))
        if b <= a:
            return np.full((len(t), 3), np.nan)
        return mag_on_imu_clock(t, MagSeries(seg.mag_key, m[a:b, 0], m[a:b, 1:4]))

    def _in_air(self, seg: _Segment, t: np.ndarray) -> np.ndarray:
        if seg.phase is None:
            if seg.baro.n:
                seg.phase = PhaseTracker("baro height")
            elif seg.gps.n and (seg.gps.column(7) >= 3).any():
                seg.phase = PhaseTracker("GPS height")
            else:
                return np.full(len(t), np.nan)
            self._event(float(t[0]), "info", f"ground/air phase from {seg.phase.source}")
        n_before = seg.phase.n
        if seg.phase.source == "baro height":
            rows = seg.baro.view()[seg.height_done:]
            seg.phase.add(rows[:, 0], pressure_height(np.where(rows[:, 1] > 1e3, rows[:, 1], np.nan)))
        else:
            rows = seg.gps.view()[seg.height_done:]
            seg.phase.add(rows[:, 0], np.where(rows[:, 7] >= 3, rows[:, 3], np.nan))
        seg.height_done += len(rows)
        phase = seg.phase.series()
        for i in range(max(n_before, 1), len(phase.t)):
            if phase.in_air[i] != phase.in_air[i - 1]:
                self._event(float(phase.t[i]), "info", ("in the air" if phase.in_air[i] else "on the ground")
                            + f" ({seg.phase.source} {phase.height_m[i]:.1f} m above the start)")
        return seg.phase.on_clock(t)

    def _aiding(self, seg: _Segment, t: np.ndarray) -> aid.Aiding:
        """GPS and baro samples not fused yet, on this chunk's IMU times."""
        g = seg.gps.view()
        k = int(np.searchsorted(g[:, 0], t[-1], side="right"))
        rows = g[seg.gps_done:k]
        gps = GpsSeries("GPS", rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], rows[:, 4:7],
                        rows[:, 7].astype(int), rows[:, 8].astype(int), rows[:, 9]) if len(rows) else None
        seg.gps_done = max(seg.gps_done, k)
        p = seg.baro.view()
        k = int(np.searchsorted(p[:, 0], t[-1], side="right"))
        rows = p[seg.baro_done:k]
        baro = BaroSeries("BARO", rows[:, 0], rows[:, 1], rows[:, 2]) if len(rows) else None
        seg.baro_done = max(seg.baro_done, k)
        out = aid.build(t, gps, baro, origin=seg.origin, baro_zero=seg.baro_zero)
        seg.origin, seg.baro_zero = out.origin, out.baro_zero
        return out

    # ------------------------------------------------------------ results

    @property
    def started(self) -> bool:
        return any(s.est for s in self.segments)

    def reference_series(self, seg: _Segment | None = None) -> AttitudeSeries | None:
        """The reference of a segment (default the current one): ATTITUDE (or
        ATTITUDE_QUATERNION) for "autopilot", SIMSTATE for "truth"."""
        seg = seg or self.seg
        keys = ("truth",) if self.reference == "truth" else ("autopilot", "autopilot_q")
        for key in keys:
            store = seg.att.get(key)
            if store is not None and store.n:
                rows = store.view()
                return AttitudeSeries({"autopilot": "ATTITUDE", "autopilot_q": "ATTITUDE_QUATERNION",
                                       "truth": "SIMSTATE"}[key], rows[:, 0], rows[:, 1:5])
        return None

    def autopilot_series(self, seg: _Segment | None = None) -> AttitudeSeries | None:
        seg = seg or self.seg
        for key, source in (("autopilot", "ATTITUDE"), ("autopilot_q", "ATTITUDE_QUATERNION")):
            store = seg.att.get(key)
            if store is not None and store.n:
                rows = store.view()
                return AttitudeSeries(source, rows[:, 0], rows[:, 1:5])
        return None

    def estimate_series(self, name: str, seg: _Segment | None = None) -> AttitudeSeries | None:
        store = (seg or self.seg).est.get(name)
        if store is None or not store.n:
            return None
        rows = store.view()
        return AttitudeSeries(name, rows[:, 0], rows[:, 1:5])

    def rolling_mae(self, window_s: float) -> dict[str, tuple[float, float, float]]:
        """Per estimator, MAE (degrees) of roll, pitch, yaw over the last ``window_s`` of the
        reference (no warm-up; yaw without a heading reference aligned over the window)."""
        ref = self.reference_series()
        out = {}
        if ref is None or not len(ref.t):
            return out
        for name in self.names:
            e = self.estimate_series(name)
            if e is None:
                continue
            t_end = min(float(ref.t[-1]), float(e.t[-1]))
            r0, r1 = np.searchsorted(ref.t, [t_end - window_s, t_end], side="right")
            e0 = max(int(np.searchsorted(e.t, t_end - window_s - 1.0)) - 1, 0)
            if r1 <= r0:
                continue
            c = compare(AttitudeSeries(ref.source, ref.t[r0:r1], ref.q[r0:r1]),
                        AttitudeSeries(name, e.t[e0:], e.q[e0:]), warmup_s=0.0,
                        align_yaw=not self.has_heading.get(name, True), name=name)
            out[name] = tuple(c.axes[a].mae if c.axes[a] is not None else math.nan for a in AXES)
        return out

    def errors(self, name: str, t_from: float) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Estimate - reference (degrees) at the reference times after ``t_from`` the estimate
        covers: (t, (N, 3) error, scored). Yaw without a heading reference has the offset of its
        run's first scored second removed (as the final metrics do)."""
        seg = self.seg
        ref, e = self.reference_series(), self.estimate_series(name)
        if ref is None or e is None:
            return None
        r0 = int(np.searchsorted(ref.t, t_from, side="right"))
        r1 = int(np.searchsorted(ref.t, e.t[-1], side="right"))
        if r1 <= r0:
            return None
        e0 = max(int(np.searchsorted(e.t, ref.t[r0])) - 1, 0)
        c = compare(AttitudeSeries(ref.source, ref.t[r0:r1], ref.q[r0:r1]),
                    AttitudeSeries(name, e.t[e0:], e.q[e0:]), warmup_s=0.0, name=name)
        err = c.error_deg
        scored = np.isfinite(err).all(axis=1) & (c.t >= float(e.t[0]) + self.warmup_s)
        if not self.has_heading.get(name, True):
            offset = seg.yaw_offset.get(name)
            if offset is None and scored.any():
                first = scored & (c.t < c.t[scored][0] + 1.0)
                offset = seg.yaw_offset[name] = circular_mean_deg(err[first, 2])
            err = err.copy()
            err[:, 2] = quat.wrap_deg(err[:, 2] - (offset or 0.0))
        return c.t, err, scored

    def final_comparisons(self) -> tuple[dict[str, Comparison], _Segment | None]:
        """Each estimator (and, against truth, the autopilot) scored over the clock segment
        with most estimates, as replay scores a log: (comparisons, that segment)."""
        candidates = [s for s in self.segments if s.est]
        if not candidates:
            return {}, None
        seg = max(candidates, key=lambda s: max(g.n for g in s.est.values()))
        ref = self.reference_series(seg)
        out = {}
        if ref is None:
            return out, seg
        for name in self.names:
            e = self.estimate_series(name, seg)
            if e is not None:
                out[name] = compare(ref, e, warmup_s=self.warmup_s, name=name,
                                    align_yaw=not self.has_heading.get(name, True), restarts=seg.restarts)
        ap = self.autopilot_series(seg)
        if self.reference == "truth" and ap is not None:
            out["autopilot"] = compare(ref, ap, warmup_s=self.warmup_s, name="autopilot")
        return out, seg

    def _event(self, t: float, level: str, text: str) -> None:
        self.events.append(Event(t, level, text))


def _within(row, limits) -> bool:
    for cols, limit in limits:
        if math.sqrt(sum(v * v for v in row[cols])) >= limit or any(v != v for v in row[cols]):
            return False
    return True


def _rate(t: np.ndarray) -> float:
    return float(1.0 / np.median(np.diff(t))) if len(t) > 1 else 0.0
