"""BROAD's HDF5 trials (Laidig et al. 2021, doi:10.3390/data6070072, CC BY 4.0): a handheld IMU
with optical motion-capture truth, read into a ``Flight`` whose ``truth`` is the optical attitude.

| dataset | unit in the file | in the Flight |
|---|---|---|
| imu_gyr, imu_acc (N×3, IMU frame) | rad/s, m/s² | ``imu["imu"]``, FRD body |
| imu_mag (N×3, IMU frame) | µT | ``mag["imu"]``, tesla, FRD body |
| opt_quat (N×4 w,x,y,z: IMU frame -> ENU; NaN where the cameras lost the markers) | - | ``truth``: body -> NED, NaN rows left out |
| movement (N bool) | - | ``unscored_spans``: the rest phases between, not scored |
| attribute sampling_rate | Hz | times: sample index / rate, s |

Frames. The IMU frame's z reads +g at rest (z up), ours is FRD (level and still the specific force
reads (0, 0, -g)). The body is the IMU frame turned 180° about x: v_body = (x, -y, -z), the
quaternion (0, 1, 0, 0), its own inverse. The truth turns IMU -> ENU; NED from ENU is the 180° turn
about the axis (1, 1, 0)/√2 (N = E_y, E = E_x, D = -U): q_ned_enu = (0, 1/√2, 1/√2, 0). So

    q_ned_body = q_ned_enu ⊗ q_enu_imu ⊗ q_imu_body,    q_imu_body = (0, 1, 0, 0).

Checked on the shared trials (tests/test_broad.py): at rest the accelerometer reads (0, 0, -g)
within its tilt, and the truth's tilt matches the accelerometer's.

The truth's north is the magnetometer's (magnetic north): with declination 0 the 9D estimators'
heading RMSE on trial 02 is 1.4-2.0° (the published Madgwick 1.3°). So the declination is 0, said
as the source's own (``declination.for_flight``), not warned of as unknown.

The gyro's samples are taken as the rate over the step that ends at each (``ImuSeries.rate_over_step``),
as the dataset's own filters take them (VQF, by the dataset's authors, integrates each sample over
the step before it): the truth is synchronised to the IMU on that reading. Measured on the 8 trials
(6D median inclination RMSE): mahony 0.61° as samples of the rate at their time (the two ends'
mean), 0.53° as means over the step; fast rotation (07) 1.67° -> 1.07°, VQF's own 1.02°
(``scripts/judge_estimators.py``).
"""
from __future__ import annotations

import json
import os

import numpy as np

from ..errors import InputError
from ..flight import AttitudeSeries, Flight, ImuSeries, MagSeries
from ..quaternion import multiply

HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
DATASETS = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "movement")
NEEDS_H5PY = "reading BROAD's HDF5 trials needs h5py: pip install 'mavattitude[broad]'"
MICROTESLA = 1e-6
Q_NED_ENU = np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])
Q_IMU_BODY = np.array([0.0, 1.0, 0.0, 0.0])  # 180° about x: IMU (z up) to FRD
IMU_TO_BODY = np.array([1.0, -1.0, -1.0])  # the same turn on vectors: (x, -y, -z)
SOURCE = "imu"  # the series' name: a trial has one IMU


def looks_like_broad(path: str, head: bytes) -> bool:
    """An HDF5 file (its signature at the start) holding BROAD's datasets."""
    if not head.startswith(HDF5_SIGNATURE):
        return False
    h5py = _h5py(path)
    try:
        with h5py.File(path, "r") as f:
            return all(name in f for name in DATASETS)
    except OSError:
        return False


def read_broad(path: str) -> Flight:
    """One trial as a Flight (the module docstring); InputError for a file that cannot be used."""
    h5py = _h5py(path)
    try:
        with h5py.File(path, "r") as f:
            data = {name: np.asarray(f[name]) for name in DATASETS}
            rate = float(f.attrs.get("sampling_rate", np.nan))
    except (OSError, KeyError) as exc:
        raise InputError(path, f"not a readable BROAD trial ({exc})") from None
    n = len(data["imu_gyr"])
    shapes = {"imu_gyr": (n, 3), "imu_acc": (n, 3), "imu_mag": (n, 3), "opt_quat": (n, 4), "movement": (n,)}
    for name, shape in shapes.items():
        if data[name].shape != shape:
            raise InputError(path, f"BROAD dataset {name} has shape {data[name].shape}, expected {shape}")
    if not (np.isfinite(rate) and rate > 0):
        raise InputError(path, f"BROAD attribute sampling_rate is {rate}, expected a rate in Hz above 0")
    if n < 2:
        raise InputError(path, f"a BROAD trial of {n} sample(s): nothing to estimate from")
    t = np.arange(n) / rate
    gyro = data["imu_gyr"].astype(float) * IMU_TO_BODY
    accel = data["imu_acc"].astype(float) * IMU_TO_BODY
    field = data["imu_mag"].astype(float) * IMU_TO_BODY * MICROTESLA
    q = data["opt_quat"].astype(float)
    seen = np.isfinite(q).all(axis=1)
    q_truth = multiply(multiply(Q_NED_ENU, q[seen]), Q_IMU_BODY)
    flight = Flight(path=path, format="broad", segments=[(float(t[0]), float(t[-1]))],
                    message_counts={name: n for name in DATASETS})
    flight.imu[SOURCE] = ImuSeries(SOURCE, t, gyro, accel, rate_over_step=True)
    flight.mag[SOURCE] = MagSeries(SOURCE, t, field)
    flight.truth = AttitudeSeries("opt_quat", t[seen], q_truth)
    flight.unscored_spans = rest_spans(t, data["movement"].astype(bool))
    flight.vehicle, flight.firmware = "BROAD", trial_identity(path)
    flight.notes.append("BROAD trial (Laidig et al. 2021, doi:10.3390/data6070072, CC BY 4.0): the truth is the "
                        "optical attitude; only its movement phases are scored")
    if not seen.all():
        flight.notes.append(f"{n - int(seen.sum())} truth samples without the markers (NaN) left out")
    return flight


def rest_spans(t: np.ndarray, movement: np.ndarray) -> list[tuple[float, float]]:
    """(first, last) time of every run of samples outside ``movement``: the spans not scored."""
    still = np.concatenate([[False], ~movement, [False]])
    starts = np.flatnonzero(~still[:-1] & still[1:])
    ends = np.flatnonzero(still[:-1] & ~still[1:]) - 1
    return [(float(t[a]), float(t[b])) for a, b in zip(starts, ends)]


def trial_identity(path: str) -> str:
    """"BROAD trial 02 (undisturbed, rotation, slow, no_breaks)" from trials.json beside the file,
    else "BROAD trial 02"."""
    stem = os.path.splitext(os.path.basename(path))[0]
    number = stem.split("_")[0]
    groups = trial_groups(path).get(stem)
    inside = [g for g in groups or () if g != "all_trials"]
    return f"BROAD trial {number}" + (f" ({', '.join(inside)})" if inside else "")


def trial_groups(path: str) -> dict[str, list[str]]:
    """{trial name: its groups} from the trials.json in the folder of ``path``; {} where there is
    none or it cannot be read."""
    try:
        with open(os.path.join(os.path.dirname(os.path.abspath(path)), "trials.json")) as f:
            trials = json.load(f)["trials"]
        return {name: list(info["groups"]) for name, info in trials.items()}
    except (OSError, ValueError, KeyError, TypeError):
        return {}


def _h5py(path: str):
    try:
        import h5py
    except ImportError:
        raise InputError(path, NEEDS_H5PY) from None
    return h5py
