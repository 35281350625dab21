"""``mavattitude tune``: an estimator's parameters fitted to a set of logs, and how much of the
fit holds on logs it was not fitted to.

- **Search space**: the fields whose ``param`` declares a search range (``params.search_space``),
  less those the user fixed with ``--set``. A ``--params`` file gives the starting values.
- **Objective**: the median, mean or geometric mean over the training logs of each log's tilt
  error (the mean of roll and pitch MAE, °; ``evalreport.tilt_score``), each log replayed as ``evaluate``
  replays it (``evaluate.Workers``: here, a process pool or a Dask cluster). A log the trial's
  parameters make diverge (non-finite attitude, or a failure) counts as ``DIVERGED_DEG``: a
  number, never an error, so the search learns to stay away.
- **Search**: Optuna's TPE sampler, the starting values as the first trial (so a fit is never
  worse than the start on its own logs). With ``study_path`` the trials go to an SQLite file:
  a stopped run resumes, each study named by its estimator, logs and settings.
- **Cross-validation**: the logs are dealt into K folds (seeded shuffle); each fold is held out
  once while the others are fitted, and scored with the start and with that fit. Every log is
  held out exactly once, so the held-out figures cover every log, each scored by a fit that
  never saw it. A last fit on all logs gives the parameters written out.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import random
import sys
import time
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import InputError, UsageError
from .evalreport import tilt_score
from ..core.params import Search, build, search_space
from .replay import ReplaySettings
from ..progress import clock

DIVERGED_DEG = 90.0  # a log's tilt error when the estimate diverged: as if the filter knew no tilt
OBJECTIVES = ("median", "mean", "geomean")


@dataclass
class TuneSettings:
    estimator: str
    replay: ReplaySettings  # names = (estimator,); --params and --set as the user gave them
    trials: int = 50  # per fit
    folds: int = 5
    objective: str = "median"
    seed: int = 0


@dataclass
class Fit:
    """One study: the logs it was fitted on, its start and its best."""
    train: list[str]
    start_value: float  # the objective with the starting parameters
    best_value: float
    best: dict[str, float]  # the searched fields' best values
    trials: int  # complete trials in the study
    held_out: list[str] = field(default_factory=list)
    held_out_start: dict[str, float] = field(default_factory=dict)  # log -> tilt error
    held_out_tuned: dict[str, float] = field(default_factory=dict)


@dataclass
class TuneResult:
    estimator: str
    objective: str
    space: dict[str, Search]
    start: dict[str, object]  # the starting values of the searched fields
    logs: list[str]  # the logs tuned on
    left_out: dict[str, str]  # log -> why it was not used (failed or not scorable at the start)
    folds: list[Fit]
    final: Fit
    penalised: int = 0  # log replays counted as diverged over the whole run
    seconds: float = 0.0  # wall time of the run

    def held_out(self) -> tuple[dict[str, float], dict[str, float]]:
        """Every cross-validated log's tilt error (start, tuned), each scored by the fit of
        the fold that held it out."""
        start, tuned = {}, {}
        for fit in self.folds:
            start.update(fit.held_out_start)
            tuned.update(fit.held_out_tuned)
        return start, tuned

    def as_dict(self) -> dict:
        start, tuned = self.held_out()
        return {"estimator": self.estimator, "objective": self.objective,
                "space": {k: str(v) for k, v in self.space.items()}, "start": self.start,
                "logs": self.logs, "left_out": self.left_out, "penalised_replays": self.penalised,
                "seconds": round(self.seconds, 1),
                "folds": [dataclasses.asdict(f) for f in self.folds],
                "held_out": None if not start else {
                    "start": summary(list(start.values())), "tuned": summary(list(tuned.values())),
                    "better": sum(tuned[k] < start[k] for k in start), "worse": sum(tuned[k] > start[k] for k in start)},
                "final": dataclasses.asdict(self.final)}


def summary(values: list[float]) -> dict[str, float]:
    return {**{objective: aggregate(values, objective) for objective in OBJECTIVES}, "logs": len(values)}


def aggregate(values, objective: str) -> float:
    """The median, mean or geometric mean of tilt errors. The geometric mean weighs a change on
    each log by its ratio: 10 % better counts the same on a 0.5° log as on a 5° one."""
    values = np.asarray(list(values), dtype=float)
    if objective == "geomean":
        return float(np.exp(np.mean(np.log(np.maximum(values, 1e-6)))))
    return float(np.median(values) if objective == "median" else np.mean(values))


def space_for(settings: TuneSettings) -> dict[str, Search]:
    """The fields searched: those with a search range, less those fixed by --set. UsageError
    when nothing is left, or for the paper's own filter (strict: its values are published)."""
    from ..estimators import ESTIMATORS
    from ..core.params import parse_assignment

    name = settings.estimator
    space = search_space(ESTIMATORS[name].Params)
    fixed = {field for est, field, _ in map(parse_assignment, settings.replay.assignments) if est == name}
    chosen = build([name], settings.replay.file_values, settings.replay.assignments,
                   source=settings.replay.params_source)[name]
    if getattr(chosen, "strict", False):
        raise UsageError(f"{name}.strict is on: the paper's filter runs its published values, so there is "
                         "nothing to tune (leave strict off)")
    space = {k: v for k, v in space.items() if k not in fixed}
    if not space:
        raise UsageError(f"nothing to tune: every parameter {name} searches is fixed by --set")
    return space


def start_values(settings: TuneSettings, space: dict[str, Search]) -> dict[str, object]:
    """The searched fields' values before tuning: the defaults, or the --params file's."""
    chosen = build([settings.estimator], settings.replay.file_values, settings.replay.assignments,
                   source=settings.replay.params_source)[settings.estimator]
    return {k: getattr(chosen, k) for k in space}


def deal_folds(logs: list[str], folds: int, seed: int) -> list[list[str]]:
    """The held-out logs of each fold: the logs shuffled (seeded) and dealt round."""
    order = sorted(logs)
    random.Random(seed).shuffle(order)
    return [sorted(order[k::folds]) for k in range(folds)]


class Scorer:
    """Each log's tilt error under given parameter values, replayed by ``workers``; a
    (log, values) pair already scored in this run is not replayed again."""

    def __init__(self, workers, settings: TuneSettings):
        self.workers, self.settings = workers, settings
        self.known: dict[tuple, float] = {}
        self.records: dict[str, dict] = {}  # log -> its record at the start values (first scoring)
        self.penalised = 0

    def __call__(self, logs: list[str], values: dict[str, object], screening: bool = False) -> dict[str, float]:
        """{log: tilt error}. A log with nothing scored is NaN when ``screening`` (the start
        values: such a log is left out), else it counts as diverged: those values broke it."""
        key = tuple(sorted(values.items()))
        todo = [log for log in logs if (log, key) not in self.known]
        if todo:
            name = self.settings.estimator
            file_values = {k: dict(v) for k, v in (self.settings.replay.file_values or {}).items()}
            file_values.setdefault(name, {}).update(values)
            trial = replace(self.settings.replay, file_values=file_values, params_source="tune")

            def finished(record: dict) -> None:
                self.records.setdefault(record["log"], record)
                score = log_score(record, name)
                self.penalised += score == DIVERGED_DEG or (math.isnan(score) and not screening)
                self.known[record["log"], key] = score

            # largest first: the longest replay starts at once, not last
            self.workers.run(sorted(todo, key=_size, reverse=True), trial, finished)
        scores = {log: self.known[log, key] for log in logs}
        return scores if screening else {log: DIVERGED_DEG if math.isnan(v) else v for log, v in scores.items()}


def _size(path: str) -> int:
    try:
        return os.path.getsize(path)
    except OSError:
        return 0


def log_score(record: dict, name: str) -> float:
    """A replayed log's tilt error (°) for ``name``; ``DIVERGED_DEG`` where the estimate went
    non-finite or the replay failed; NaN where there was nothing to score."""
    if record["status"] == "skipped":
        return math.nan
    if record["status"] != "ok":
        return DIVERGED_DEG
    metrics = record["metrics"].get(name, {})
    if metrics.get("nonfinite_samples"):
        return DIVERGED_DEG
    score = tilt_score(metrics)
    return math.nan if score is None else min(score, DIVERGED_DEG)


def study_name(settings: TuneSettings, train: list[str], space: dict[str, Search]) -> str:
    """A name that changes with anything that changes the trials' values: the estimator, the
    logs, the replay settings and the code (``evaluate.settings_key``), the objective, the
    search space and the seed."""
    from .evaluate import settings_key

    what = json.dumps([sorted(os.path.abspath(p) for p in train), settings_key(settings.replay),
                       settings.objective, {k: str(v) for k, v in space.items()}, settings.seed])
    return f"{settings.estimator}-{hashlib.sha1(what.encode()).hexdigest()[:12]}"


def open_study(path, option: str = "--study"):
    """The Optuna storage in the SQLite file ``path`` (``outputs.Outputs.database`` checked it
    is new or Optuna's), opened and written to once now: a database SQLite cannot read, or
    cannot write (a read-only file or folder), is one line naming it, not SQLAlchemy's
    traceback minutes later."""
    import optuna
    from sqlalchemy.exc import SQLAlchemyError

    try:
        storage = optuna.storages.RDBStorage(f"sqlite:///{path}")
        with storage.engine.begin() as db:  # a write that changes nothing: SQLite says now if it cannot
            db.exec_driver_sql("UPDATE version_info SET schema_version = schema_version")
    except SQLAlchemyError as exc:
        reason = str(getattr(exc, "orig", None) or exc).splitlines()[0]
        raise InputError(path, f"{option}: cannot open the study ({reason})") from None
    except RuntimeError as exc:  # Optuna: a study of another Optuna version's schema
        raise InputError(path, f"{option}: cannot open the study ({exc})") from None
    return storage


def fit(scorer: Scorer, settings: TuneSettings, train: list[str], space: dict[str, Search],
        start: dict[str, object], storage, seed: int, progress) -> Fit:
    """Search ``space`` for the values with the lowest objective over ``train``: ``trials``
    complete trials in all, counting those a stopped run already stored."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        sampler = optuna.samplers.TPESampler(seed=seed, multivariate=True)
    study = optuna.create_study(storage=storage, study_name=study_name(settings, train, space),
                                sampler=sampler, direction="minimize", load_if_exists=True)
    complete = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    start_value = aggregate(scorer(train, start).values(), settings.objective)
    if not complete:
        study.enqueue_trial(start)
    progress.fit_started(len(complete), start_value, min((t.value for t in complete), default=start_value))
    for _ in range(len(complete), settings.trials):
        trial = study.ask()
        try:
            values = {k: _suggest(trial, k, s) for k, s in space.items()}
            scores = scorer(train, values)
            value = aggregate(scores.values(), settings.objective)
            trial.set_user_attr("diverged_logs", sum(v == DIVERGED_DEG for v in scores.values()))
        except BaseException:
            study.tell(trial, state=optuna.trial.TrialState.FAIL)
            raise
        study.tell(trial, value)
        progress.trial_done(value)
    best = study.best_trial
    return Fit(train=list(train), start_value=start_value, best_value=float(best.value),
               best={k: best.params[k] for k in space},
               trials=sum(t.state == optuna.trial.TrialState.COMPLETE for t in study.trials))


def _suggest(trial, name: str, search: Search):
    if search.integer:
        return trial.suggest_int(name, int(search.lo), int(search.hi), log=search.log)
    return trial.suggest_float(name, search.lo, search.hi, log=search.log)


def tune(logs: list[str], settings: TuneSettings, workers, storage=None, progress=None) -> TuneResult:
    """Cross-validate (``settings.folds`` folds; fewer than 2 logs or folds: none), then fit on
    every log. ``storage``: an Optuna storage (``open_study``, or an SQLite URL) or None (in memory)."""
    began = time.monotonic()
    space = space_for(settings)
    start = start_values(settings, space)
    scorer = Scorer(workers, settings)
    progress = progress or TrialProgress(settings.estimator, quiet=True)
    progress.say(f"scoring {len(logs)} logs with the starting values")
    first = scorer(logs, start, screening=True)
    left_out = {log: _why_unscored(scorer.records[log], first[log]) for log in logs
                if not math.isfinite(first[log]) or first[log] == DIVERGED_DEG}
    used = [log for log in logs if log not in left_out]
    if not used:  # the logs' fault, not the command line's
        raise InputError(", ".join(logs[:3]) + (f" and {len(logs) - 3} more" if len(logs) > 3 else ""),
                         f"no log could be scored for {settings.estimator}: "
                         + "; ".join(f"{k}: {v}" for k, v in left_out.items()))
    folds = min(settings.folds, len(used)) if settings.folds >= 2 and len(used) >= 2 else 0
    progress.plan(folds + 1, settings.trials)
    fits = []
    for k, held_out in enumerate(deal_folds(used, folds, settings.seed) if folds else []):
        train = [log for log in used if log not in held_out]
        progress.fit_label = f"fold {k + 1}/{folds}"
        result = fit(scorer, settings, train, space, start, storage, settings.seed + k, progress)
        result.held_out = held_out
        result.held_out_start = scorer(held_out, start)
        result.held_out_tuned = scorer(held_out, result.best)
        fits.append(result)
    progress.fit_label = f"all {len(used)} logs"
    final = fit(scorer, settings, used, space, start, storage, settings.seed + folds, progress)
    progress.close()
    return TuneResult(settings.estimator, settings.objective, space, start, used, left_out, fits, final,
                      scorer.penalised, time.monotonic() - began)


def _why_unscored(record: dict, score: float) -> str:
    if record["status"] != "ok":
        return record["error"] or record["status"]
    return "the starting values diverge" if score == DIVERGED_DEG else "nothing scored (no longer than --warmup?)"


class TrialProgress:
    """Trials done, the best so far and the time left, on stderr: a line redrawn on a
    terminal, else a line per trial; nothing when ``quiet``."""

    def __init__(self, estimator: str, stream=None, quiet: bool = False):
        self.estimator, self.quiet = estimator, quiet
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.fit_label = ""
        self.total = self.done = self.run = 0  # trials in all, done (stored ones too), run here
        self.trial, self.start_value, self.best = 0, math.nan, math.nan  # of the fit under way
        self.start = time.monotonic()
        self._open = False  # a redrawn line is on the terminal

    def plan(self, fits: int, trials: int) -> None:
        self.total = fits * trials

    def say(self, text: str) -> None:
        if not self.quiet:
            self._end_line()
            print(f"tune {self.estimator}: {text}", file=self.stream, flush=True)

    def fit_started(self, stored: int, start_value: float, best: float) -> None:
        self.done += stored
        self.start_value, self.best, self.trial = start_value, best, stored
        if stored:
            self.say(f"{self.fit_label}: resuming after {stored} stored trials")

    def trial_done(self, value: float) -> None:
        self.done += 1
        self.run += 1
        self.trial += 1
        self.best = min(self.best, value)
        if self.quiet:
            return
        elapsed = time.monotonic() - self.start
        left = elapsed / self.run * (self.total - self.done)
        line = (f"tune {self.estimator} {self.fit_label}: trial {self.trial}, {value:.3f}°; best {self.best:.3f}° "
                f"(start {self.start_value:.3f}°); {self.done}/{self.total} trials, {clock(elapsed)} elapsed, "
                f"about {clock(left)} left")
        print(f"\r{line}   " if self.tty else line, end="" if self.tty else "\n", file=self.stream, flush=True)
        self._open = self.tty

    def _end_line(self) -> None:
        if self._open:
            print(file=self.stream, flush=True)
            self._open = False

    def close(self) -> None:
        self._end_line()


def report_text(result: TuneResult) -> str:
    """The cross-validation table and the final fit, as ``tune`` prints them."""
    obj = result.objective
    lines = [f"{result.estimator}: {obj} tilt error (mean of roll and pitch MAE, °) over {len(result.logs)} logs; "
             f"searched: " + ", ".join(f"{k} {v}" for k, v in result.space.items())]
    for log, why in result.left_out.items():
        lines.append(f"  left out {log}: {why}")
    if result.folds:
        lines += ["", f"{len(result.folds)}-fold cross-validation by log (each fold fitted on the other folds' logs, "
                      "scored on its own):",
                  f"{'fold':>4} {'fit on':>6} {'start':>7} {'tuned':>7}  {'held out':>8} {'start':>7} {'tuned':>7}"]
        for k, f in enumerate(result.folds):
            lines.append(f"{k + 1:>4} {len(f.train):>6} {f.start_value:7.3f} {f.best_value:7.3f}  "
                         f"{len(f.held_out):>8} {aggregate(f.held_out_start.values(), obj):7.3f} "
                         f"{aggregate(f.held_out_tuned.values(), obj):7.3f}")
        start, tuned = result.held_out()
        s, t = aggregate(start.values(), obj), aggregate(tuned.values(), obj)
        better = sum(tuned[k] < start[k] for k in start)
        worse = sum(tuned[k] > start[k] for k in start)
        lines.append(f"held out, all {len(start)} logs: " + ", ".join(
            f"{o} {aggregate(start.values(), o):.3f} -> {aggregate(tuned.values(), o):.3f}" for o in OBJECTIVES)
            + f"; better on {better}, worse on {worse} logs")
        if t >= s:
            lines.append(f"warning: on logs it was not fitted to, tuning did not lower the {obj} ({s:.3f} -> "
                         f"{t:.3f}): the fit below suits these logs, not other flights; keep the start, or "
                         "tune on more logs, alike in vehicle and flying")
    f = result.final
    lines += ["", f"fit on all {len(f.train)} logs ({f.trials} trials): {obj} {f.start_value:.3f} -> "
                  f"{f.best_value:.3f} ({_change(f.start_value, f.best_value)})"]
    width = max(len(k) for k in f.best)
    for k, v in f.best.items():
        lines.append(f"  {k:<{width}} {_g(result.start[k]):>10} -> {_g(v)}")
    if result.penalised:
        lines.append(f"({result.penalised} replays diverged and counted as {DIVERGED_DEG:g}°)")
    return "\n".join(lines)


def _change(before: float, after: float) -> str:
    return f"{100 * (after - before) / before:+.1f} %" if before else "n/a"


def _g(x) -> str:
    return f"{x:.4g}" if isinstance(x, float) else str(x)


def tuned_toml(result: TuneResult, settings: TuneSettings, command: str) -> str:
    """The parameters to run with (``--params``): the user's file values and --set values for
    this estimator, and the final fit's values, with where they came from in a comment."""
    from ..core.params import parse_assignment, to_toml

    name = settings.estimator
    chosen = build([name], settings.replay.file_values, settings.replay.assignments,
                   source=settings.replay.params_source)[name]
    given = set((settings.replay.file_values or {}).get(name, {}))
    given |= {field for est, field, _ in map(parse_assignment, settings.replay.assignments) if est == name}
    given |= set(result.final.best)
    table = {f.name: result.final.best.get(f.name, getattr(chosen, f.name))
             for f in dataclasses.fields(chosen) if f.name in given}
    f = result.final
    note = [f"written by: {command}",
            f"fitted on {len(f.train)} logs: {result.objective} tilt error {f.start_value:.3f} -> {f.best_value:.3f} deg"]
    if result.folds:
        start, tuned = result.held_out()
        note.append(f"{len(result.folds)}-fold held out: {aggregate(start.values(), result.objective):.3f} -> "
                    f"{aggregate(tuned.values(), result.objective):.3f} deg")
    return to_toml({name: table}, {name: "\n".join(note)})
