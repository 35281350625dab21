"""Argument types and the option groups several commands share, with one-line usage errors."""
from __future__ import annotations

import argparse
import math
import os
import re


def number(low: float, high: float = math.inf, *, above: bool = False, whole: bool = False):
    """An argparse type: a finite number from ``low`` (excluded with ``above``) to ``high``;
    ``whole`` for integers. Anything else is a usage error naming the option."""
    def parse(text: str):
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        ok = math.isfinite(value) and (value > low if above else value >= low) and value <= high
        if ok and whole and value != int(value):
            ok = False
        if not ok:
            kind = "a whole number" if whole else "a number"
            shown = (lambda x: f"{x:.0f}") if whole else (lambda x: f"{x:g}")  # 4294967295, not 4.29497e+09
            bound = f"above {shown(low)}" if above else f"at least {shown(low)}"
            limit = f" and at most {shown(high)}" if math.isfinite(high) else ""
            raise argparse.ArgumentTypeError(f"expected {kind} {bound}{limit}, not {text!r}")
        return int(value) if whole else value
    parse.__name__ = "number"
    return parse


SECONDS = number(0.0)  # zero or more
POSITIVE = number(0.0, above=True)
COUNT = number(1, whole=True)
DEGREES = number(-180.0, 180.0)
SEED = number(0, 2**32 - 1, whole=True)


def home(text: str):
    """An argparse type: --home LAT,LON[,ALT] (``declination.parse_home``); a usage error otherwise."""
    from ..declination import parse_home

    try:
        return parse_home(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


home.__name__ = "LAT,LON"


class Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors, as every other error here is; a value that starts
    with a minus and a digit is a value, not an option (``--home -35.36,149.17``), as Python
    3.13's argparse has it (before, only a plain negative number was)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(r"-\.?\d")

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")

    def _get_values(self, action, arg_strings):
        # argparse without CPython's fix gh-109475 (early 2024; 3.11.7 has it not) drops a value
        # of exactly '--' (--seed=--) as if it were the separator: the option gets [] and its
        # type and choices are never checked. Take the value as given, as the fix does.
        if action.option_strings and action.nargs is None and arg_strings == ["--"]:
            value = self._get_value(action, "--")
            self._check_value(action, value)
            return value
        return super()._get_values(action, arg_strings)


def quiet_arg(p) -> None:
    p.add_argument("-q", "--quiet", action="store_true",
                   help="no progress display (it shows on a terminal only, for work over 2 s)")


def estimation_args(p, source: str, estimators: bool = True) -> None:
    """The options replay, evaluate, tune and live share: what to run, with what, against what.
    ``source``: "log" or "vehicle", for the help texts; ``estimators``: with --estimators."""
    if estimators:
        p.add_argument("--estimators", default="mahony", metavar="LIST",
                       help="comma-separated estimator names, 'all' (ours) among them, e.g. "
                            "all,vqf,imufusion (default: mahony)")
    if source == "log":
        p.add_argument("--reference", default="autopilot", metavar="NAME",
                       help="what to score against: 'autopilot' (its attitude in use: ATT/ATTITUDE/"
                            "vehicle_attitude, default), 'truth' (the simulator's: SIM/SIMSTATE/"
                            "vehicle_attitude_groundtruth), 'ekf' (the autopilot's EKF where the log has one; evaluate "
                            "skips a log without) or any attitude stream 'mavattitude info' lists (EKF1, AHR2, XKF1[1], "
                            "...; any case). The autopilot's other streams are scored against it too, as rows "
                            "'autopilot:ALGORITHM (STREAM)'; with truth the attitude in use is the row 'autopilot'")
    else:
        p.add_argument("--reference", choices=("autopilot", "truth"), default="autopilot",
                       help="score against the autopilot's attitude (ATTITUDE, default) or the simulator's ground "
                            "truth (SIMSTATE); with truth the autopilot is scored too, as the row 'autopilot'")
    p.add_argument("--imu", default=None, metavar="SOURCE",
                   help="IMU source to estimate from, e.g. IMU[1], RAW_IMU, SCALED_IMU2, HIGHRES_IMU "
                        "(default: the fastest, most precise" + ("; see 'mavattitude info')" if source == "log"
                                                                 else " that arrives; live asks for it)"))
    if source == "log":
        quiet_arg(p)
        from ..flight import DEFAULT_FAMILIES, IMU_FAMILIES
        p.add_argument("--imu-source", choices=list(IMU_FAMILIES), default=None, dest="imu_family",
                       help="which kind of IMU data to estimate from: " + "; ".join(
                           f"{k}: {v}" for k, v in IMU_FAMILIES.items()) + " (default: the first of "
                           f"{', '.join(DEFAULT_FAMILIES)} the log has; --imu picks one series)")
    p.add_argument("--warmup", type=SECONDS, default=10.0, metavar="S",
                   help="seconds at the start not scored while estimators converge (default 10)")
    p.add_argument("--declination", type=DEGREES, default=None, metavar="DEG", dest="declination_deg",
                   help=f"magnetic declination in degrees, east positive, -180 to 180 (default: the "
                        f"{source}'s COMPASS_DEC where set by hand (COMPASS_AUTODEC=0; PX4: EKF2_MAG_DECL), "
                        "else the World Magnetic Model at --home or the first good GPS fix on the "
                        f"{source}'s date, as the autopilot computes it; else 0 with a warning)")
    p.add_argument("--home", type=home, default=None, metavar="LAT,LON",
                   help="where the vehicle flew, degrees (LAT,LON,ALT: metres above sea level too): "
                        "the declination from the World Magnetic Model there, for a "
                        f"{source} without a GPS fix (it takes the place of the fix; a declination set by "
                        "hand on the autopilot still wins)")
    p.add_argument("--no-mag", action="store_true",
                   help="ignore the magnetometer: yaw from the gyro only, compared after removing "
                        "its initial offset")
    p.add_argument("--set", action="append", metavar="NAME.PARAM=VALUE",
                   help="override an estimator parameter, e.g. ncs-eskf.h_threshold_air=0.02 "
                        "(repeatable; see 'mavattitude estimators')")
    p.add_argument("--params", metavar="FILE",
                   help="a TOML file of parameters, a [NAME] table per estimator; --set wins over it")


def workers_args(p, keeping: bool = False) -> None:
    """Where evaluate and tune replay their logs: local processes or a Dask cluster.
    ``keeping``: each worker keeps the logs it read (tune replays them once per trial)."""
    keeps = ", each keeping the logs it read" if keeping else ""
    p.add_argument("-j", "--jobs", type=COUNT, default=os.cpu_count() or 1, metavar="N",
                   help=f"logs replayed at once, one process each{keeps} (default: the CPUs, {os.cpu_count()})")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="replay on a Dask distributed cluster, e.g. tcp://HOST:8786 (pip install "
                        "'mavattitude[cluster]'); its workers read the logs at the same paths")
    p.add_argument("--ship-logs", action="store_true",
                   help="with --scheduler: send each log's bytes to the worker (workers without the files)")


def viewer_args(group) -> None:
    """Where the Rerun recording goes: one of these (a mutually exclusive group)."""
    group.add_argument("--rrd", metavar="FILE", help="write the Rerun recording to FILE")
    group.add_argument("--spawn", action="store_true", help="stream to a newly spawned Rerun viewer")
    group.add_argument("--connect", metavar="URL",
                       help="stream to a running Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy")
    group.add_argument("--web", action="store_true",
                       help="serve Rerun's web viewer (ports 9090 and 9876, or the next free ones) until Ctrl-C")


def force_arg(p) -> None:
    p.add_argument("--force", action="store_true",
                   help="write an output over an existing file of another kind (never over an "
                        "input log or parameter file)")


def trim_arg(p) -> None:
    p.add_argument("--no-trim", action="store_true",
                   help="score the estimates as estimated: without turning them by the log's board "
                        "trim (AHRS_TRIM_X/Y) first, as the autopilot turns its own attitude")


def segment_arg(p) -> None:
    p.add_argument("--segment", type=number(0, whole=True), default=None, metavar="N",
                   help="when the autopilot rebooted during the log (its clock went back), "
                        "use clock segment N (0-based); default: the longest")
