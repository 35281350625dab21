"""Rankings across logs that say when they mean something (issue 24, part 6): ``evaluate``'s
estimators ranked per reference family, each against the baseline with an interval and a test,
and a log's win counted only where the winner's lead exceeds the reference's own spread.

The reference is the autopilot's estimate, and which estimator looks best depends on which of
its estimators that is (DCM or EKF): the logs are grouped by the reference's family
(``reference_family``) and ranked apart, and across all.

Against the baseline (``--baseline``), per estimator, on the logs both were scored on:

- the **paired median ratio**: the median over logs of (estimator tilt / baseline tilt on the
  same log), with a **bootstrap 95 % interval** over logs: the logs resampled with replacement
  ``RESAMPLES`` times (seeded: the same records give the same interval), the 2.5th and 97.5th
  percentiles of the resampled medians;
- a two-sided **sign test**: the count of logs where the estimator is lower than the baseline,
  ties dropped, against a fair coin (exact binomial: p = min(1, 2 · P(X ≤ min(k, n - k)))).

A **win** on a log: the best estimator's lead over the second best exceeds that log's reference
spread (``reference_spread_deg``: the smallest tilt error of the autopilot's other estimators
against the reference). A lead inside the spread wins nothing: the autopilot's own estimators
differ by more than that. A log without a spread (no other autopilot stream, or an older record)
counts a win for any lead > 0, in a count of its own.

Functions here take the records (``evaluate``'s dicts) or scores and return numbers: no I/O.
"""
from __future__ import annotations

import math

import numpy as np

RESAMPLES = 2000
SEED = 0
LEVEL = 0.05  # a 95 % interval; a sign test "shows" a difference at p < LEVEL
FAMILIES = ("DCM", "EKF", "truth", "other")


def reference_algorithm(record: dict) -> str:
    """The algorithm of the record's reference ("DCM", "EKF3 core 0", "PX4 EKF2", ...); "unknown"
    for a record from before the reference was named."""
    return record.get("reference_algorithm") or "unknown"


def reference_spread(record: dict) -> float | None:
    """The record's reference spread (°), None where the log has none or the record predates it."""
    spread = record.get("reference_spread_deg")
    return float(spread) if spread is not None and math.isfinite(spread) else None


def reference_family(algorithm: str, reference: str = "autopilot") -> str:
    """"DCM", "EKF" (EKF1, EKF2, EKF3 and their cores, PX4 EKF2), "truth" (``--reference truth``,
    or SITL whose attitude is the simulator's truth) or "other" (PX4's Q filter, unknown, ...)."""
    if reference == "truth" or algorithm in ("truth", "SITL"):
        return "truth"
    if algorithm == "DCM":
        return "DCM"
    if algorithm.startswith(("EKF", "PX4 EKF2")):
        return "EKF"
    return "other"


def sign_test_p(better: int, worse: int) -> float:
    """Two-sided exact sign test: the chance of a split at least this uneven from a fair coin."""
    n = better + worse
    if n == 0:
        return 1.0
    tail = sum(math.comb(n, i) for i in range(min(better, worse) + 1)) / 2.0 ** n
    return min(1.0, 2.0 * tail)


def bootstrap_median_interval(values, resamples: int = RESAMPLES, seed: int = SEED) -> tuple[float, float]:
    """The 95 % percentile interval of the median of ``values``, resampled with replacement."""
    values = np.asarray(values, dtype=float)
    rng = np.random.default_rng(seed)
    medians = np.median(values[rng.integers(0, len(values), (resamples, len(values)))], axis=1)
    low, high = np.percentile(medians, [100 * LEVEL / 2, 100 * (1 - LEVEL / 2)])
    return float(low), float(high)


def against_baseline(by_log: dict[str, dict[str, float]], name: str, baseline: str) -> dict:
    """``name`` against ``baseline`` on the logs both were scored on (``by_log``: log -> estimator
    -> tilt score): logs, lower/higher/tied counts, median ratio, its interval, sign-test p, and
    the median difference (estimator - baseline, °)."""
    pairs = [(s[name], s[baseline]) for s in by_log.values() if name in s and baseline in s and s[baseline] > 0]
    better = sum(a < b for a, b in pairs)
    worse = sum(a > b for a, b in pairs)
    out = {"logs": len(pairs), "lower": better, "higher": worse, "ties": len(pairs) - better - worse,
           "median_ratio": None, "interval": None, "p": float(f"{sign_test_p(better, worse):.4g}"),
           "median_difference_deg": None}
    if pairs:
        ratios = np.array([a / b for a, b in pairs])
        out["median_ratio"] = _round(np.median(ratios))
        out["median_difference_deg"] = _round(np.median([a - b for a, b in pairs]))
        out["interval"] = [_round(x) for x in bootstrap_median_interval(ratios)]
    return out


def counted_wins(by_log: dict[str, dict[str, float]], spreads: dict[str, float | None],
                 names: list[str]) -> dict:
    """Per estimator, the logs it wins: ``over_spread`` where the log has a spread and the lead
    over the second best exceeds it, ``no_spread`` where it has none and the lead is > 0; and the
    logs whose best lead is inside the spread (``within_spread``: no winner)."""
    wins = {name: {"over_spread": 0, "no_spread": 0} for name in names}
    within = 0
    for log, s in by_log.items():
        ranked = sorted((v, n) for n, v in s.items() if n in names)
        if len(ranked) < 2:
            continue
        (best, winner), (second, _) = ranked[0], ranked[1]
        lead, spread = second - best, spreads.get(log)
        if spread is None:
            wins[winner]["no_spread"] += lead > 0
        elif lead > spread:
            wins[winner]["over_spread"] += 1
        else:
            within += 1
    return {"estimators": wins, "within_spread": within,
            "logs_with_spread": sum(spreads.get(log) is not None for log in by_log),
            "logs_without_spread": sum(spreads.get(log) is None for log in by_log)}


def rankings(records: list[dict], by_log: dict[str, dict[str, float]], names: list[str], baseline: str,
             reference: str) -> dict:
    """Per group ("all", then each reference family that has logs): the logs, each estimator's
    median and wins, its comparison with the baseline, and the plain-language lines."""
    family = {r["log"]: reference_family(reference_algorithm(r), reference) for r in records}
    spreads = {r["log"]: reference_spread(r) for r in records}
    by_log = {log: s for log, s in by_log.items() if any(n in s for n in names)}
    groups = {"all": by_log}
    for f in FAMILIES:
        logs = {log: s for log, s in by_log.items() if family.get(log) == f}
        if logs:
            groups[f] = logs
    out = {}
    for group, logs in groups.items():
        wins = counted_wins(logs, spreads, names)
        estimators = {}
        for name in names:
            values = [s[name] for s in logs.values() if name in s]
            estimators[name] = {"logs": len(values), "median": _round(np.median(values)) if values else None,
                                "wins": wins["estimators"][name],
                                "vs_baseline": against_baseline(logs, name, baseline) if name != baseline else None}
        spread_values = [spreads[log] for log in logs if spreads.get(log) is not None]
        entry = {"logs": len(logs), "within_spread": wins["within_spread"],
                 "median_spread_deg": _round(np.median(spread_values)) if spread_values else None,
                 "logs_with_spread": wins["logs_with_spread"], "logs_without_spread": wins["logs_without_spread"],
                 "estimators": estimators}
        entry["plain"] = plain_lines(entry, baseline)
        out[group] = entry
    return out


def plain_lines(group: dict, baseline: str) -> list[str]:
    """What the group's data supports and what it does not, one line per estimator (lowest median
    ratio first), then how the wins were counted."""
    lines = []
    compared = [(e["vs_baseline"], name) for name, e in group["estimators"].items()
                if e["vs_baseline"] is not None and e["vs_baseline"]["logs"]]
    spread = group["median_spread_deg"]
    for v, name in sorted(compared, key=lambda c: c[0]["median_ratio"]):
        low, high = v["interval"]
        tied = f" ({v['ties']} tied)" if v["ties"] else ""
        said = (f"{name} is lower than {baseline} on {v['lower']} of {v['logs']} logs{tied}, "
                f"median ratio {v['median_ratio']:.2f} "
                f"[{low:.2f}, {high:.2f}], p = {format_p(v['p'])}: ")
        if v["lower"] + v["higher"] < 6:
            said += (f"too few logs for the sign test to show anything (with {v['lower'] + v['higher']} untied "
                     f"logs p cannot fall below {LEVEL:g})")
        elif low <= 1.0 <= high:
            said += "the interval includes 1: no difference shown"
        else:
            direction = "lower" if high < 1.0 else "higher"
            if v["p"] < LEVEL:
                said += f"{direction} than {baseline} on these logs (the interval excludes 1, p < {LEVEL:g})"
                if spread is not None and abs(v["median_difference_deg"]) < spread:
                    said += (f", by a median {abs(v['median_difference_deg']):.2f}°, inside the autopilot's own "
                             f"spread on these logs (median {spread:.2f}°)")
            else:
                said += (f"the interval excludes 1 but the sign test does not show it {direction} on most logs "
                         f"(p ≥ {LEVEL:g})")
        lines.append(said)
    having = group["logs_with_spread"]
    counted = (f"a win is counted where the best estimator leads the second best by more than the log's reference "
               f"spread ({logs_text(having)} {'has' if having == 1 else 'have'} one; on {group['within_spread']} of "
               "them the lead is inside it and nobody wins)")
    if group["logs_without_spread"]:
        counted += (f"; on the {logs_text(group['logs_without_spread'])} with no reference spread (no other autopilot "
                    "estimate) any lead > 0 wins, counted apart")
    return lines + [counted[0].upper() + counted[1:] + "."]


def logs_text(n: int) -> str:
    return f"{n} log{'s' if n != 1 else ''}"


def format_p(p: float) -> str:
    return f"{p:.3f}" if p >= 0.001 else f"{p:.1e}"


def _round(x) -> float:
    return round(float(x), 4)
