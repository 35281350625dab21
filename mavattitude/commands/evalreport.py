"""What ``evaluate`` writes from its per-log records: the results table (CSV, Parquet), the
summary (JSON), the report (Markdown) and its figure (SVG).

A log's score for an estimator is its tilt error: the mean of its roll and pitch MAE (°)
against the reference. Yaw is left out of the ranking: without a compass it is the gyro's
alone and aligned at the start (drift, not a heading), and with one it depends on the
declination the log gives. A log whose scores are not meaningful (``imucheck``: an IMU too
slow to follow the vehicle) is left out of every ranking and listed with the reason. The
rankings per reference family, the comparison with the baseline (interval, sign test) and the
wins counted above the reference's spread are ``rankstats``'.
"""
from __future__ import annotations

import csv
import io
import math

import numpy as np

from ..outputs import SVG_MARK, WRITTEN_BY, json_text
from ..scoring.rankstats import FAMILIES, RESAMPLES, format_p, logs_text, rankings
from ..scoring.refcheck import DISAGREE_DEG, DISAGREE_MIN_S
from .report import BUCKET_KEYS

AXES = ("roll", "pitch", "yaw")
METRIC_KEYS = ("n", "mae", "rmse", "mse", "r2", "max", "sigma1", "sigma3")
FACT_KEYS = ("format", "vehicle", "firmware", "imu_source", "imu_rate_hz", "duration_s", "gps", "compass",
             "baro", "clock_segments", "gaps", "reference_suspect", "accel_scale_error", "not_meaningful",
             "declination_deg", "declination_source")
# per log, from the record (evaluate._replay): the reference's stream and algorithm, and its spread
# (the smallest tilt MAE of the autopilot's other streams against it, report.reference_spread)
REFERENCE_KEYS = ("reference_stream", "reference_algorithm", "reference_spread_deg")
PAPER_001_CHAIN = ("ncs-eskf", "eskf", "ekf", "mahony")  # paper 001's ranking, best first


def tilt_score(metrics: dict) -> float | None:
    """The mean of roll and pitch MAE (°), None where either was not scored."""
    roll, pitch = metrics.get("roll"), metrics.get("pitch")
    if not roll or not pitch or roll.get("mae") is None or pitch.get("mae") is None:
        return None
    return 0.5 * (roll["mae"] + pitch["mae"])


def not_meaningful(record: dict) -> str | None:
    """Why a log's scores are not meaningful (it is left out of the rankings); None: they are."""
    return record.get("facts", {}).get("not_meaningful")


def scores(records: list[dict]) -> dict[str, dict[str, float]]:
    """log -> estimator (and "autopilot" against truth) -> tilt score, for the logs that ran
    and whose scores are meaningful."""
    out = {}
    for r in records:
        if r["status"] == "ok" and not not_meaningful(r):
            out[r["log"]] = {name: s for name, m in r["metrics"].items() if (s := tilt_score(m)) is not None}
    return out


# ---------------------------------------------------------------- results table


def result_rows(records: list[dict]) -> list[dict]:
    """One row per log × estimator × axis with every metric, and the log's facts; one row per
    log that failed or was skipped."""
    rows = []
    for r in records:
        base = {"log": r["log"], "status": r["status"], "error": r.get("error") or ""}
        base.update({k: r.get("facts", {}).get(k) for k in FACT_KEYS})
        base.update({k: r.get(k) for k in REFERENCE_KEYS})
        if r["status"] != "ok":
            rows.append(dict(base, estimator="", axis=""))
            continue
        for name, m in r["metrics"].items():
            for axis in AXES:
                row = dict(base, estimator=name, axis=axis)
                values = m.get(axis) or {}
                row.update({k: values.get(k) for k in METRIC_KEYS})
                row["yaw_aligned"] = values.get("aligned") if axis == "yaw" else None
                buckets = values.get("buckets") or {}
                row.update({f"share_{k}": buckets.get(k) for k in BUCKET_KEYS})
                rows.append(row)
    return rows


def columns() -> list[str]:
    return (["log", "status", "error", *FACT_KEYS, *REFERENCE_KEYS, "estimator", "axis", *METRIC_KEYS, "yaw_aligned"]
            + [f"share_{k}" for k in BUCKET_KEYS])


def results_csv(rows: list[dict]) -> str:
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=columns(), lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: "" if v is None else v for k, v in row.items()})
    return out.getvalue()


def has_parquet() -> bool:
    """Whether pyarrow is installed (``pip install 'mavattitude[parquet]'``)."""
    import importlib.util
    return importlib.util.find_spec("pyarrow") is not None


def write_parquet(rows: list[dict], path) -> None:
    """The results table as Parquet (needs pyarrow)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_pylist([{k: row.get(k) for k in columns()} for row in rows])
    pq.write_table(table.replace_schema_metadata({"written_by": WRITTEN_BY}), str(path))  # ours (outputs.is_kind)


# ---------------------------------------------------------------- summary


def summarize(records: list[dict], names: list[str], baseline: str, reference: str) -> dict:
    """Per estimator: median, mean and 90th percentile of the tilt score over the logs, the
    geometric mean of its ratio to ``baseline``, wins (best on a log, by any lead), mean rank, the
    logs where it is ≤ 0.8× and > 2× the baseline; the rankings per reference family
    (``rankstats.rankings``); the paper-001 check; the failures."""
    by_log = scores(records)
    estimators = {}
    ranks = {name: [] for name in names}
    wins = dict.fromkeys(names, 0)
    for s in by_log.values():
        on_log = {n: v for n, v in s.items() if n in names}
        for n, v in on_log.items():  # 1 = best; a tie shares its places' mean
            below = sum(w < v for w in on_log.values())
            ties = sum(w == v for w in on_log.values())
            ranks[n].append(below + (ties + 1) / 2)
            wins[n] += below == 0  # each of a tie for best wins
    for name in names:
        values = np.array([s[name] for s in by_log.values() if name in s])
        pairs = [(s[name], s[baseline]) for s in by_log.values()
                 if name in s and baseline in s and s[baseline] > 0]
        ratios = np.array([a / b for a, b in pairs if a > 0])
        worst = sorted(((s[name], log) for log, s in by_log.items() if name in s), reverse=True)[:3]
        estimators[name] = {
            "logs": int(len(values)),
            "median": _round(np.median(values)) if len(values) else None,
            "mean": _round(values.mean()) if len(values) else None,
            "p90": _round(np.percentile(values, 90)) if len(values) else None,
            "ratio_to_baseline_geomean": _round(math.exp(np.log(ratios).mean())) if len(ratios) else None,
            "wins": wins[name],
            "mean_rank": _round(np.mean(ranks[name])) if ranks[name] else None,
            "logs_at_most_0.8x_baseline": int(sum(a <= 0.8 * b for a, b in pairs)),
            "logs_over_2x_baseline": int(sum(a > 2.0 * b for a, b in pairs)),
            "worst_logs": [{"log": log, "score": _round(v)} for v, log in worst],
        }
    summary = {
        "reference": reference, "baseline": baseline, "score": "mean of roll and pitch MAE, degrees",
        "logs": len(records), "scored": len(by_log),
        "not_meaningful": [{"log": r["log"], "why": not_meaningful(r)} for r in records
                           if r["status"] == "ok" and not_meaningful(r)],
        "failed": [{"log": r["log"], "error": r["error"]} for r in records if r["status"] == "failed"],
        "skipped": [{"log": r["log"], "why": r["error"]} for r in records if r["status"] == "skipped"],
        "reference_suspect": [{"log": r["log"], "spans": r.get("suspects", []), "notes": r.get("reference_notes", [])}
                              for r in records if r.get("suspects") or r.get("reference_notes")],
        "references": [{"log": r["log"], "stream": r.get("reference_stream"), "algorithm": r.get("reference_algorithm"),
                        "spread_deg": r.get("reference_spread_deg")} for r in records if r["status"] == "ok"],
        "estimators": estimators,
        "by_reference": rankings(records, by_log, names, baseline, reference),
    }
    if all(n in names for n in PAPER_001_CHAIN):
        summary["paper_001_ranking"] = paper_001_check(by_log)
    if reference.lower() == "truth":
        summary["against_autopilot"] = against_autopilot(by_log, names)
    return summary


def paper_001_check(by_log: dict) -> dict:
    """Paper 001 ranks NCS-ESKF < ESKF < EKF < Mahony (tilt error): on how many logs each step
    and the whole chain hold, of the logs where all four were scored."""
    logs = [s for s in by_log.values() if all(n in s for n in PAPER_001_CHAIN)]
    steps = {}
    for better, worse in zip(PAPER_001_CHAIN, PAPER_001_CHAIN[1:]):
        steps[f"{better} < {worse}"] = int(sum(s[better] < s[worse] for s in logs))
    chain = int(sum(all(s[a] < s[b] for a, b in zip(PAPER_001_CHAIN, PAPER_001_CHAIN[1:])) for s in logs))
    return {"logs": len(logs), "steps": steps, "whole_chain": chain}


def against_autopilot(by_log: dict, names: list[str]) -> dict:
    """Against ground truth, each estimator next to the autopilot's own EKF: logs where it is
    better, and the median ratio of their scores."""
    out = {}
    for name in names:
        pairs = [(s[name], s["autopilot"]) for s in by_log.values() if name in s and "autopilot" in s]
        ratios = [a / b for a, b in pairs if b > 0]
        out[name] = {"logs": len(pairs), "better": int(sum(a < b for a, b in pairs)),
                     "median_ratio": _round(float(np.median(ratios))) if ratios else None}
    return out


def _round(x) -> float:
    return round(float(x), 3)


# ---------------------------------------------------------------- report


def report_markdown(summary: dict, command: str, figure: str | None) -> str:
    est = summary["estimators"]
    order = sorted(est, key=lambda n: (est[n]["median"] is None, est[n]["median"] or 0.0))
    ok = summary["scored"]
    lines = [
        "# Attitude estimators across logs", "",
        f"`{command}`", "",
        f"{summary['logs']} logs: {ok} scored, {len(summary['not_meaningful'])} not meaningful (left out), "
        f"{len(summary['failed'])} failed, {len(summary['skipped'])} skipped. "
        f"Score: the mean of roll and pitch MAE (°) against the {summary['reference']} reference, after the "
        f"warm-up; ratios are to `{summary['baseline']}` on the same log. Yaw is not ranked: an estimator "
        "without a heading reference gives the gyro's drift, not a heading.", "",
        "## Ranking", "",
        "| estimator | logs | median | mean | p90 | × baseline (geo-mean) | best on log | mean rank "
        "| ≤ 0.8× baseline | > 2× baseline |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name in order:
        e = est[name]
        lines.append(f"| {name} | {e['logs']} | {_f(e['median'])} | {_f(e['mean'])} | {_f(e['p90'])} "
                     f"| {_f(e['ratio_to_baseline_geomean'])} | {e['wins']} | {_f(e['mean_rank'], 2)} "
                     f"| {e['logs_at_most_0.8x_baseline']} | {e['logs_over_2x_baseline']} |")
    lines += ["", "\"Best on log\" counts any lead; the rankings below count a win only above the log's "
              "reference spread."]
    lines += reference_sections(summary)
    if figure:
        lines += ["", f"![tilt error per estimator across logs]({figure})", "",
                  "Each dot is a log (its tilt score, log scale); the box spans the middle half, the bar "
                  "is the median."]
    check = summary.get("paper_001_ranking")
    if check:
        n = check["logs"]
        lines += ["", "## Paper 001's ranking: NCS-ESKF < ESKF < EKF < Mahony", "",
                  f"Of the {n} logs where all four were scored:", ""]
        lines += [f"- {step}: holds on {count} of {n}" for step, count in check["steps"].items()]
        lines.append(f"- the whole chain: holds on {check['whole_chain']} of {n}")
    ap = summary.get("against_autopilot")
    if ap:
        lines += ["", "## Against the autopilot's own estimate (ground truth)", "",
                  "| estimator | logs | better than the autopilot | median ratio to the autopilot |",
                  "|---|---|---|---|"]
        lines += [f"| {n} | {v['logs']} | {v['better']} | {_f(v['median_ratio'])} |" for n, v in ap.items()]
    lines += ["", "## Worst logs per estimator", "", "| estimator | worst logs (score, °) |", "|---|---|"]
    for name in order:
        worst = ", ".join(f"`{_short(w['log'])}` {w['score']:.2f}" for w in est[name]["worst_logs"])
        lines.append(f"| {name} | {worst or '-'} |")
    if summary.get("references"):
        lines += ["", "## Reference per log", "",
                  f"What `--reference {summary['reference']}` scored each log against: "
                  + references_said(summary["references"]) + ". Spread: the smallest tilt error (mean of roll and "
                  "pitch MAE, °) of the autopilot's other streams against the reference, the least it is known to "
                  "be uncertain by.", "",
                  "| log | stream | algorithm | spread |", "|---|---|---|---|"]
        lines += [f"| `{_short(e['log'])}` | {e['stream'] or '-'} | {e['algorithm'] or '-'} | {_f(e['spread_deg'])} |"
                  for e in summary["references"]]
    if summary["reference_suspect"]:
        lines += ["", "## References not trusted", "",
                  "Spans where the log's own IMU says the autopilot's attitude cannot be right, or where the "
                  f"autopilot's own estimators disagree in tilt by more than {DISAGREE_DEG:g}° for "
                  f"{DISAGREE_MIN_S:g} s or longer; they are "
                  "not scored (the rest of the log is). A note on the whole log says what was done instead.", ""]
        for entry in summary["reference_suspect"]:
            said = [f"{s['start_s']:.1f}-{s['end_s']:.1f} s: {s['detail']}" for s in entry["spans"]]
            said += [f"whole log: {n['detail']}" for n in entry["notes"]]
            lines.append(f"- `{_short(entry['log'])}`: {'; '.join(said)}")
    if summary["not_meaningful"]:
        lines += ["", "## Not meaningful (left out of the ranking)", ""]
        lines += [f"- `{n['log']}`: {n['why']}" for n in summary["not_meaningful"]]
    if summary["failed"]:
        lines += ["", "## Failed", ""] + [f"- {f['error']}" for f in summary["failed"]]
    if summary["skipped"]:
        lines += ["", "## Skipped", ""] + [f"- `{s['log']}`: {s['why']}" for s in summary["skipped"]]
    return "\n".join(lines) + "\n"


def references_said(references: list[dict]) -> str:
    """How many logs were scored against each algorithm: "DCM (ATT) 12 logs, EKF3 core 0 (XKF1[0]) 3 logs"."""
    counts: dict[str, int] = {}
    for e in references:
        said = f"{e['algorithm']} ({e['stream']})"
        counts[said] = counts.get(said, 0) + 1
    return ", ".join(f"{said} {n} log{'s' if n != 1 else ''}" for said, n in counts.items())


GROUP_TITLES = {"all": "All logs", "DCM": "DCM-reference logs", "EKF": "EKF-reference logs (EKF1, EKF2, EKF3, "
                "PX4 EKF2)", "truth": "Ground-truth reference", "other": "Other references (PX4 Q, unknown)"}


def reference_sections(summary: dict) -> list[str]:
    """The report's rankings per reference family: a table and the plain-language lines each."""
    groups = summary.get("by_reference") or {}
    baseline = summary["baseline"]
    lines = ["", "## Rankings per reference algorithm", "",
             "The reference is one of the autopilot's estimators, and the ranking depends on which: the logs "
             "are ranked apart by the family of their reference, and across all. Against "
             f"`{baseline}`: the median over logs of the ratio of tilt scores on the same log, its bootstrap "
             f"95 % interval (logs resampled with replacement, {RESAMPLES:,} times, seeded) and a two-sided sign "
             "test on the logs where the estimator is lower (ties dropped). A win: the best estimator's lead "
             "over the second best exceeds the log's reference spread (the smallest tilt error of the "
             "autopilot's other estimators against the reference)."]
    for group in ("all", *FAMILIES):
        g = groups.get(group)
        if not g:
            continue
        est = g["estimators"]
        order = sorted(est, key=lambda n: (est[n]["median"] is None, est[n]["median"] or 0.0))
        spread = "" if g["median_spread_deg"] is None else (f"; the autopilot's own spread: median "
                                                            f"{g['median_spread_deg']:.2f}° over "
                                                            f"{g['logs_with_spread']} of them")
        lines += ["", f"### {GROUP_TITLES[group]}: {logs_text(g['logs'])}{spread}", "",
                  f"| estimator | logs | median | wins (lead > spread) | wins (no spread, lead > 0) "
                  f"| lower than {baseline} | median ratio [95 % interval] | sign test p |",
                  "|---|---|---|---|---|---|---|---|"]
        for name in order:
            e, v = est[name], est[name]["vs_baseline"]
            versus = ("(baseline)", "-", "-") if v is None else \
                (f"{v['lower']} of {v['logs']}", _ratio(v), "-" if not v["logs"] else format_p(v["p"]))
            lines.append(f"| {name} | {e['logs']} | {_f(e['median'])} | {e['wins']['over_spread']} "
                         f"| {e['wins']['no_spread']} | {' | '.join(versus)} |")
        lines += [""] + [f"- {line}" for line in g["plain"]]
    return lines


def _ratio(v: dict) -> str:
    if v["median_ratio"] is None:
        return "-"
    return f"{v['median_ratio']:.2f} [{v['interval'][0]:.2f}, {v['interval'][1]:.2f}]"


def ranking_text(summary: dict) -> str:
    """The ranking for the terminal."""
    est = summary["estimators"]
    order = sorted(est, key=lambda n: (est[n]["median"] is None, est[n]["median"] or 0.0))
    lines = [f"tilt error (mean of roll and pitch MAE, °) against the {summary['reference']} reference, "
             f"over {summary['scored']} logs; ratio to {summary['baseline']}",
             f"{'estimator':12s} {'logs':>5s} {'median':>7s} {'mean':>7s} {'p90':>7s} {'×base':>6s} "
             f"{'best':>5s} {'rank':>5s} {'≤0.8×':>6s} {'>2×':>4s}"]
    for n in order:
        e = est[n]
        lines.append(f"{n:12s} {e['logs']:5d} {_f(e['median']):>7s} {_f(e['mean']):>7s} {_f(e['p90']):>7s} "
                     f"{_f(e['ratio_to_baseline_geomean'], 2):>6s} {e['wins']:5d} {_f(e['mean_rank'], 2):>5s} "
                     f"{e['logs_at_most_0.8x_baseline']:6d} {e['logs_over_2x_baseline']:4d}")
    if summary.get("references"):
        lines.append(f"reference per log: {references_said(summary['references'])} (report.md lists each)")
    for group, g in (summary.get("by_reference") or {}).items():
        if group != "all" and len(summary["by_reference"]) == 2:
            continue  # one family: the same logs as "all"
        lines.append(f"{GROUP_TITLES[group]} ({logs_text(g['logs'])}):")
        lines += [f"  {line}" for line in g["plain"]]
    left_out = summary.get("not_meaningful", [])
    if left_out:
        named = "; ".join(f"{_short(n['log'])}: {n['why']}" for n in left_out[:3])
        lines.append(f"left out, scores not meaningful: {len(left_out)} log{'s' if len(left_out) != 1 else ''} "
                     f"({named}{'; ...' if len(left_out) > 3 else ''}; see report.md)")
    return "\n".join(lines)


def _f(x, digits: int = 3) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def _short(path: str) -> str:
    return path.replace("\\", "/").rsplit("/", 1)[-1]


def summary_json(summary: dict) -> str:
    return json_text(summary)


# ---------------------------------------------------------------- figure


def strip_plot_svg(records: list[dict], names: list[str]) -> str:
    """Tilt score per estimator across logs, as an SVG: a row per estimator (best median on
    top), a dot per log on a log-scale axis, the quartile box and the median."""
    by_log = scores(records)
    values = {n: np.array([s[n] for s in by_log.values() if n in s and s[n] > 0]) for n in names}
    if "autopilot" in {n for s in by_log.values() for n in s}:
        values["autopilot"] = np.array([s["autopilot"] for s in by_log.values() if s.get("autopilot", 0) > 0])
    values = {n: v for n, v in values.items() if len(v)}
    order = sorted(values, key=lambda n: np.median(values[n]))
    everything = np.concatenate(list(values.values())) if values else np.array([0.1, 10.0])
    lo = 10 ** math.floor(math.log10(everything.min()))
    hi = 10 ** math.ceil(math.log10(everything.max()))
    left, right, top, row_h = 110, 30, 20, 34
    width, height = 760, top + row_h * len(order) + 50

    def x_of(v):
        return left + (math.log10(v) - math.log10(lo)) / (math.log10(hi) - math.log10(lo)) * (width - left - right)

    rng = np.random.default_rng(0)
    parts = [f"{SVG_MARK.decode()} evaluate -->",  # ours (outputs.is_kind)
             f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
             f'font-family="sans-serif" font-size="12">',
             f'<rect width="{width}" height="{height}" fill="white"/>']
    decade = lo
    while decade <= hi * 1.001:
        for k in range(1, 10):
            v = decade * k
            if v > hi * 1.001:
                break
            x = x_of(v)
            strong = k == 1
            parts.append(f'<line x1="{x:.1f}" y1="{top}" x2="{x:.1f}" y2="{height - 40}" '
                         f'stroke="{"#bbb" if strong else "#eee"}"/>')
            if k in (1, 2, 5):
                parts.append(f'<text x="{x:.1f}" y="{height - 25}" text-anchor="middle">{v:g}°</text>')
        decade *= 10
    parts.append(f'<text x="{(left + width - right) / 2:.0f}" y="{height - 6}" text-anchor="middle">'
                 'tilt error per log: mean of roll and pitch MAE (°, log scale)</text>')
    for row, name in enumerate(order):
        v = values[name]
        y = top + row_h * row + row_h / 2
        q1, med, q3 = np.percentile(v, [25, 50, 75])
        parts.append(f'<text x="{left - 8}" y="{y + 4:.1f}" text-anchor="end">{name}</text>')
        parts.append(f'<rect x="{x_of(q1):.1f}" y="{y - 10:.1f}" width="{max(x_of(q3) - x_of(q1), 1):.1f}" '
                     f'height="20" fill="#dde8f5" stroke="#6b8fbf"/>')
        parts.append(f'<line x1="{x_of(med):.1f}" y1="{y - 12:.1f}" x2="{x_of(med):.1f}" y2="{y + 12:.1f}" '
                     f'stroke="#1f4e8c" stroke-width="2.5"/>')
        for value in v:
            jitter = rng.uniform(-7, 7)
            parts.append(f'<circle cx="{x_of(value):.1f}" cy="{y + jitter:.1f}" r="2.6" '
                         f'fill="#c0392b" fill-opacity="0.65"/>')
    parts.append("</svg>")
    return "\n".join(parts) + "\n"
