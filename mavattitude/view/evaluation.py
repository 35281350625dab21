"""``evaluate --rrd``: one recording for a run over many logs.

Timeline ``"log"``: a sequence, the log's number in the run (0, 1, ...), so each log is one step
on the x axis of the plot and one row of the logs tab.

- ``<root>/tilt``  SeriesPoints: an estimator's tilt error (deg, the mean of roll and pitch MAE)
  on each log it scored (``<root>`` as in a replay: ``est/<name>``, the autopilot against truth
  ``ref/autopilot``): a strip per estimator across the logs; hiding the root hides it
- ``logs/<k>_<log name>``  TextLog at step k: one entity per log, its line giving its number,
  name, status, scores and the ``mavattitude replay`` command that writes its own recording
- ``report``  TextDocument: the run's report.md
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from .blueprint import text_log_columns
from .style import _part, assign_colors, series_root

TIMELINE = "log"
_LEVELS = {"ok": rr.TextLogLevel.INFO, "not meaningful": rr.TextLogLevel.WARN, "skipped": rr.TextLogLevel.WARN,
           "failed": rr.TextLogLevel.ERROR}


@dataclass
class LogRow:
    """One log of the run, as the recording shows it."""
    log: str  # its path
    status: str  # "ok", "not meaningful", "skipped", "failed"
    scores: dict[str, float] = field(default_factory=dict)  # estimator -> tilt error, deg
    note: str = ""  # why it failed, was skipped or is not meaningful
    command: str = ""  # the replay that writes its own recording


def log_line(k: int, row: LogRow) -> str:
    """The logs tab's line: "#3 flight.bin: ok · cpf-ekf 0.88 · mahony 1.25 | mavattitude replay ..."."""
    scores = " · ".join(f"{n} {v:.2f}" for n, v in sorted(row.scores.items(), key=lambda kv: kv[1]))
    what = row.status + (f" ({row.note})" if row.note else "")
    return f"#{k} {Path(row.log).name}: {what}" + (f" · {scores}" if scores else "") + \
        (f" | own recording: {row.command}" if row.command else "")


def log_evaluation(rec: rr.RecordingStream, rows: Sequence[LogRow], names: Sequence[str], report_md: str) -> None:
    """The run into ``rec``, with its blueprint (see the module docstring)."""
    names = list(names) + (["autopilot"] if any("autopilot" in r.scores for r in rows) else [])
    colors = assign_colors(names)
    values = np.array([v for r in rows for v in r.scores.values()] or [1.0])
    top = float(np.percentile(values, 95)) * 1.3  # a log where one estimator diverged runs off the top
    rec.send_blueprint(rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.TimeSeriesView(origin="/", name="tilt error per log (deg; x: the log's number in the logs tab)",
                                   contents=[f"+ /{series_root(n)}/tilt" for n in names],
                                   axis_y=rrb.ScalarAxis(range=(0.0, top)),
                                   axis_x=rrb.TimeAxis(view_range=rr.TimeRange(  # every log, none on an edge
                                       start=rrb.TimeRangeBoundary.absolute(seq=-1),
                                       end=rrb.TimeRangeBoundary.absolute(seq=len(rows)))),
                                   plot_legend=rrb.PlotLegend(corner="LeftTop", visible=True)),
                rrb.TextLogView(origin="logs", name="logs: number, scores, the command for its own recording",
                                columns=text_log_columns(TIMELINE)),
                row_shares=[3, 2]),
            rrb.TextDocumentView(origin="report", name="report"),
            column_shares=[3, 2]),
        rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline=TIMELINE)), make_active=True, make_default=True)
    rec.log("report", rr.TextDocument(report_md, media_type="text/markdown"), static=True)
    for name in names:
        steps = [k for k, r in enumerate(rows) if name in r.scores]
        if not steps:
            continue
        path = f"{series_root(name)}/tilt"
        rec.log(path, rr.SeriesPoints(colors=[colors[name]], names=[name], markers=["Circle"], marker_sizes=[4.0]),
                static=True)
        rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, sequence=steps)],
                         columns=rr.Scalars.columns(scalars=[rows[k].scores[name] for k in steps]))
    for k, row in enumerate(rows):
        rec.set_time(TIMELINE, sequence=k)
        rec.log(f"logs/{k:03d}_{_part(Path(row.log).name)}",
                rr.TextLog(log_line(k, row), level=_LEVELS.get(row.status, rr.TextLogLevel.INFO)))
