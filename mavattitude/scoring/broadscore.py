"""BROAD's error measures (Laidig et al. 2021, "BROAD — A Benchmark for Robust Inertial Orientation
Estimation", Data 6(7), section 3; doi:10.3390/data6070072, CC BY 4.0) and its published figures.

The error quaternion is taken in the world frame, q_err = q_est ⊗ q_ref⁻¹ (both body -> world;
the dataset's ``calculateErrorQuatEarth``), and over the scored samples:

- total: its whole angle, 2·acos(|w|);
- heading: its turn about the world's vertical, 2·atan(|z / w|);
- inclination: what remains, the tilt, 2·acos(√(w² + z²));

each as an RMSE in degrees. The vertical is z in ENU and in NED alike (up or down: the angles are
absolute), so the measures are taken on our NED attitudes as they are. A turn about the vertical
applied to the estimate, q_z ⊗ q_est, leaves w² + z² of q_err unchanged: the inclination of an
estimate with no heading reference (6D, no compass) needs no alignment of its yaw, and its heading
and total are not measures of it (n/a).

Used for every comparison against a truth (BROAD's optical truth or a simulator's), next to the
Euler angles of ``metrics``. ``evaluate`` on BROAD trials shows them per trial and per group of the
dataset's trials.json, beside the dataset's published Madgwick and Mahony results.
"""
from __future__ import annotations

import json
import os

import numpy as np

from ..flight import AttitudeSeries
from .metrics import Comparison
from ..quaternion import conjugate, interpolate, multiply, normalize

MEASURES = ("total_rmse_deg", "heading_rmse_deg", "inclination_rmse_deg")
PUBLISHED = {"Madgwick": "published_madgwick_average_rmse.json", "Mahony": "published_mahony_average_rmse.json"}
ATTRIBUTION = ("BROAD: Laidig, Caruso, Cereatti, Seel 2021, doi:10.3390/data6070072, CC BY 4.0; published figures "
               "with one parameter set for all its trials (TAGP), 9D")


def error_angles(q_ref: np.ndarray, q_est: np.ndarray) -> dict[str, np.ndarray]:
    """Per sample: total, heading and inclination angle (rad) of q_est ⊗ q_ref⁻¹."""
    w, x, y, z = normalize(multiply(q_est, conjugate(q_ref))).T
    # the dataset's arccos forms as atan2 of the unit quaternion's parts: equal, and exact near 0
    # (acos near 1 loses half the digits: 1e-8 rad where the error is nil)
    return {"total": 2 * np.arctan2(np.sqrt(x * x + y * y + z * z), np.abs(w)),
            "heading": 2 * np.arctan2(np.abs(z), np.abs(w)),
            "inclination": 2 * np.arctan2(np.hypot(x, y), np.hypot(w, z))}


def broad_measures(reference: AttitudeSeries, estimate: AttitudeSeries, comparison: Comparison,
                   heading: bool = True) -> dict[str, float | None] | None:
    """Total, heading and inclination RMSE (degrees) over the samples ``comparison`` scored (its
    warm-up, gaps and unscored spans left out alike). ``heading``: whether the estimator had a
    heading reference; without one its total and heading are None. None where nothing was scored."""
    t = comparison.t[comparison.scored]
    if not len(t):
        return None
    ok = np.isfinite(estimate.q).all(axis=1) & np.isfinite(estimate.t)
    order = np.argsort(estimate.t[ok], kind="stable")
    q_est = interpolate(estimate.t[ok][order], estimate.q[ok][order], t)
    ref_ok = np.isfinite(reference.q).all(axis=1) & np.isfinite(reference.t)
    q_ref = interpolate(reference.t[ref_ok], reference.q[ref_ok], t)  # exact: t are the reference's own times
    angles = error_angles(q_ref, q_est)
    rmse = {name: float(np.degrees(np.sqrt(np.mean(a * a)))) for name, a in angles.items()}
    return {"total_rmse_deg": rmse["total"] if heading else None,
            "heading_rmse_deg": rmse["heading"] if heading else None,
            "inclination_rmse_deg": rmse["inclination"]}


def format_broad_table(measures: dict[str, dict | None]) -> str:
    """The replay's small table: per estimator total, heading and inclination RMSE."""
    name_w = max([len("estimator")] + [len(n) for n in measures])
    lines = ["Error-quaternion RMSE against the truth, BROAD's measures (degrees; n/a: no heading reference)",
             f"{'estimator':<{name_w}}  {'total':>8}  {'heading':>8}  {'inclination':>11}"]
    lines.append("-" * len(lines[-1]))
    for name, m in measures.items():
        cells = [_deg((m or {}).get(k)) for k in MEASURES]
        lines.append(f"{name:<{name_w}}  {cells[0]:>8}  {cells[1]:>8}  {cells[2]:>11}")
    return "\n".join(lines) + "\n"


def _deg(x) -> str:
    return "n/a" if x is None else f"{x:.2f}"


# ---------------------------------------------------------------- evaluate: per trial and group


def published_figures(folder: str) -> dict[str, dict]:
    """{"Madgwick": its JSON, "Mahony": ...} for the published files in ``folder`` ({} for none).
    Each JSON: {"trials": {trial: {"tagp_parameters": {measure: deg}}}, "groups": {group: ...}}."""
    out = {}
    for name, file in PUBLISHED.items():
        try:
            with open(os.path.join(folder, file)) as f:
                out[name] = json.load(f)
        except (OSError, ValueError):
            continue
    return out


def broad_records(records: list[dict]) -> list[dict]:
    """The scored records of BROAD trials (their facts' format "broad")."""
    return [r for r in records if r.get("status") == "ok" and r.get("facts", {}).get("format") == "broad"]


def broad_text(records: list[dict], names: list[str], measure: str = "inclination_rmse_deg") -> str:
    """``evaluate``'s BROAD tables: ``measure`` (all three when a row has them) per trial and per
    group (the trials.json beside the trials), each estimator beside the published Madgwick and
    Mahony (TAGP) figures; "" when no record is a BROAD trial."""
    from ..readers.broad import trial_groups

    broad = broad_records(records)
    if not broad:
        return ""
    folder = os.path.dirname(os.path.abspath(broad[0]["log"]))
    published = published_figures(folder)
    trial = {_stem(r["log"]): r for r in broad}
    groups: dict[str, list[str]] = {}
    for r in broad:
        for g in trial_groups(r["log"]).get(_stem(r["log"]), []):
            groups.setdefault(g, []).append(_stem(r["log"]))
    rows = list(names) + [f"{p} (published)" for p in published]
    label = {"total_rmse_deg": "total", "heading_rmse_deg": "heading", "inclination_rmse_deg": "inclination"}
    out = []
    for m in MEASURES:
        per_trial = {stem: {n: _measure(r, n, m) for n in names} for stem, r in trial.items()}
        for stem in per_trial:
            for p, data in published.items():
                per_trial[stem][f"{p} (published)"] = data.get("trials", {}).get(stem, {}) \
                    .get("tagp_parameters", {}).get(m)
        if all(v is None for row in per_trial.values() for k, v in row.items() if k in names):
            continue  # no estimator has this measure (6D: heading and total)
        out.append(_table(f"BROAD {label[m]} RMSE per trial (degrees; n/a: no heading reference)",
                          [s.split("_")[0] for s in per_trial], rows, list(per_trial.values())))
        per_group = {}
        for g, stems in groups.items():
            per_group[g] = {n: _mean([per_trial[s][n] for s in stems]) for n in names}
            for p, data in published.items():  # the published group means are over all 39 trials
                per_group[g][f"{p} (published)"] = data.get("groups", {}).get(g, {}).get("tagp_parameters", {}).get(m)
        if per_group:
            out.append(_table(f"BROAD {label[m]} RMSE per group: mean over the trials here (published: over all "
                              "the dataset's trials of the group)", list(per_group), rows, list(per_group.values())))
    out.append(ATTRIBUTION)
    return "\n".join(out) + "\n"


def _measure(record: dict, name: str, measure: str):
    return ((record.get("metrics", {}).get(name) or {}).get("broad") or {}).get(measure)


def _mean(values: list) -> float | None:
    """The mean, or None where any value is missing (a mean over fewer trials is another figure)."""
    return None if not values or any(v is None for v in values) else float(np.mean(values))


def _stem(path: str) -> str:
    return os.path.splitext(os.path.basename(path))[0]


def _table(title: str, columns: list[str], rows: list[str], values: list[dict]) -> str:
    """Rows: estimators; columns: trials or groups."""
    name_w = max(len(r) for r in rows + ["estimator"])
    widths = [max(6, len(c)) for c in columns]
    head = f"{'estimator':<{name_w}}  " + "  ".join(f"{c:>{w}}" for c, w in zip(columns, widths))
    lines = [title, head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r:<{name_w}}  " + "  ".join(f"{_deg(v.get(r)):>{w}}" for v, w in zip(values, widths)))
    return "\n".join(lines) + "\n"
