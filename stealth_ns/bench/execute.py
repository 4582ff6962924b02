"""Executing a plan: train (or reuse) every run through an executor, compare each poisoned run with
its scene's clean run (cached in the run's ``metrics.json``), and rewrite results.json and tables.md
after every run, with a progress bar across runs.
"""

from __future__ import annotations

import json
import sys
import time
import traceback
from collections.abc import Callable
from contextlib import redirect_stderr, redirect_stdout
from typing import Any

from stealth_ns.bench.executors import Executor, Job, Outcome, make_executor
from stealth_ns.bench.plan import Plan, PlannedRun
from stealth_ns.bench.results import run_entry, write_outputs
from stealth_ns.bench.tables import fmt_value
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.json_io import json_safe, write_json_atomic
from stealth_ns.method_configs.attack_experiments import (
    clean_run,
)
from stealth_ns.runs.step_log import median_step_ms
from stealth_ns.runs.training import (
    TRAIN_LOG,
    TrainRecord,
    train_progress,
)

METRICS_FILE = "metrics.json"
METRICS_LOG = "metrics.log"
#: What a cached metrics.json holds: 2 added the stealth under the post-hoc defences (version 1 had none);
#: 3: the defender's fine-tune trains the support views on their poisoned images (``support_views``).
METRICS_VERSION = 3


def cached_pair_metrics(
    poisoned: PlannedRun, poisoned_rec: TrainRecord, clean: PlannedRun, clean_rec: TrainRecord
) -> tuple[dict[str, Any], float, bool]:
    """``compare_runs`` of a poisoned run and its clean baseline, cached in ``metrics.json``.

    Returns ``(metrics, seconds, cached)``; the cache holds while neither run is retrained and the
    metrics have the same contents (:data:`METRICS_VERSION`).
    """
    cache = poisoned.spec.run_dir / METRICS_FILE
    stamp = {
        "poisoned_run_id": poisoned_rec.run_id,
        "clean_run_id": clean_rec.run_id,
        "version": METRICS_VERSION,
    }
    try:
        data = json.loads(cache.read_text())
        if data.get("stamp") == stamp and isinstance(data.get("metrics"), dict):
            return data["metrics"], float(data.get("seconds", 0.0)), True
    except (OSError, ValueError, AttributeError):
        pass
    from stealth_ns.report import numbers

    t0 = time.perf_counter()
    # loading two runs in-process is chatty (nerfstudio's console, warnings): keep it in a log
    with (poisoned.spec.run_dir / METRICS_LOG).open("w") as log, redirect_stdout(log), redirect_stderr(log):
        try:
            metrics = json_safe(numbers.compare_runs(poisoned.spec.config_path, clean.spec.config_path))
        except Exception:
            traceback.print_exc(file=log)
            raise
    seconds = round(time.perf_counter() - t0, 2)
    write_json_atomic(
        cache,
        {"stamp": stamp, "clean_config": str(clean.spec.config_path), "seconds": seconds, "metrics": metrics},
    )
    return metrics, seconds, False


def _progress_parser(bar: Any, key: str) -> Callable[[str], None]:
    """An ``on_line`` callback that shows ns-train's "STEP (P%)" progress in the bar's postfix."""
    last = [-1]

    def on_line(line: str) -> None:
        pct = train_progress(line)
        if pct is not None and int(pct) != last[0]:
            last[0] = int(pct)
            bar.set_postfix_str(f"{key} training {last[0]}%")

    return on_line


class _Bench:
    """The bookkeeping of one :func:`execute`: results entries, finished records, the bar and the log
    lines; it hears the executor's events and outcomes (:mod:`stealth_ns.bench.executors`).

    A poisoned run's metrics need its scene's clean run: with the local executor the clean run
    always comes first (the plan's order); with Ray a poisoned run that finishes first waits, and
    its metrics follow the clean run's line.
    """

    def __init__(self, plan: Plan, executor: Executor, bar: Any, started: float) -> None:
        self.plan, self.executor, self.bar, self.t0 = plan, executor, bar, started
        self.runs = {p.key: run_entry(p) for p in plan.runs}
        self.records: dict[str, TrainRecord] = {}
        self.failures: list[str] = []
        self.done = 0
        self.reported: set[str] = set()
        self.running: set[str] = set()
        """Runs handed to a parallel executor and not finished yet (the bar's postfix)."""
        self.waiting: dict[str, list[tuple[PlannedRun, TrainRecord]]] = {}
        """Clean run key -> the poisoned runs of its scene that finished before it."""

    def jobs(self) -> list[Job]:
        errors = self.plan.scene_errors
        blocked = {scene: f"scene {scene}: {err}" for scene, err in errors.items()}
        blocked.update(self.plan.run_errors)
        return [Job(p.key, p.spec, blocked.get(p.run.scene, blocked.get(p.key))) for p in self.plan.runs]

    def write(self, complete: bool = False) -> dict[str, Any]:
        return write_outputs(self.plan, self.runs, self.t0, complete, self.executor.record())

    # ---- events
    def started(self, job: Job) -> None:
        p = self.plan.get(job.key)
        training = job.blocked is None and p.status != "finished"
        if self.executor.sequential:
            self.bar.set_postfix_str(f"{p.key} {'reusing' if p.status == 'finished' else 'training'}")
        elif training:
            self.running.add(p.key)
            self.bar.set_postfix_str(f"{len(self.running)} training on {self.executor.name}")
        if training and self.bar.disable:
            log = p.spec.run_dir / TRAIN_LOG
            if self.executor.sequential:
                print(f"[{self.done + 1}/{len(self.plan.runs)}] training {p.key} (log: {log})", flush=True)
            else:
                print(f"submitted {p.key} to {self.executor.name} (log: {log})", flush=True)

    def line_callback(self, job: Job) -> Callable[[str], None]:
        return _progress_parser(self.bar, job.key)

    def retrying(self, job: Job, attempt: int, reason: str) -> None:
        self.bar.write(f"RETRY {job.key} (attempt {attempt}): {reason}")

    # ---- outcomes
    def finish(self, o: Outcome) -> None:
        """Record one finished (or failed) run, print its line, fill in metrics that can be computed."""
        p, entry = self.plan.get(o.job.key), self.runs[o.job.key]
        self.done += 1
        tag = f"[{self.done}/{len(self.plan.runs)}]"
        if p.key in self.running:
            self.running.discard(p.key)
            self.bar.set_postfix_str(f"{len(self.running)} training on {self.executor.name}")
        if o.attempts:
            entry["attempts"] = list(o.attempts)
        if o.worker:
            entry["worker"] = o.worker
        self.reported.add(p.key)
        if o.record is None:
            if o.blocked:
                entry.update(status="failed", error=o.error)
            else:
                entry.update(status="failed", error=o.error, log=str(p.spec.run_dir / TRAIN_LOG))
            tries = len(o.attempts)
            self.failures.append(p.key if tries < 2 else f"{p.key} after {tries} attempts")
            self.bar.write(f"{tag} FAILED {p.key}: {o.error}")
            self.bar.update(1)
            self._release(p, tag)
            if not o.blocked:
                self.write()
            return
        record = self.records[p.key] = o.record
        entry.update(
            status="trained" if record.trained_now else "reused",
            train_seconds=record.seconds,
            trained_at=record.finished_at,
            iterations=record.iterations,
            median_step_ms=median_step_ms(p.spec.run_dir),
            log=str(p.spec.run_dir / TRAIN_LOG),
        )
        verb = "trained" if record.trained_now else "reused"
        msg = f"{tag} {verb} {p.key} ({record.seconds:.0f} s of training)"
        if o.worker and record.trained_now:
            msg += f" on {o.worker.get('host')}"
        if o.attempts:
            msg += f" after {len(o.attempts)} failed attempt(s)"
        clean_key = clean_run(p.run.scene).key
        if not p.run.clean and clean_key not in self.reported:
            self.waiting.setdefault(clean_key, []).append((p, record))
            msg += f"; metrics once {clean_key} is done"
        elif not p.run.clean:
            msg += self._metrics(p, record, entry)
        self.bar.write(msg)
        self.bar.update(1)
        self._release(p, tag)
        self.write()

    def _metrics(self, p: PlannedRun, record: TrainRecord, entry: dict[str, Any]) -> str:
        note = _attach_metrics(self.plan, p, record, self.records, entry, self.bar)
        if "metrics_error" in entry:
            self.failures.append(f"{p.key} (metrics)")
        return note

    def _release(self, p: PlannedRun, tag: str) -> None:
        """After a clean run: the metrics of the poisoned runs of its scene that waited for it."""
        for q, record in self.waiting.pop(p.key, []):
            note = self._metrics(q, record, self.runs[q.key])
            self.bar.write(f"{' ' * len(tag)} metrics of {q.key}{note}")


def execute(plan: Plan, executor: Executor | None = None) -> dict[str, Any]:
    """Train (or reuse) every run of the plan, compute the metrics, write tables.md and results.json.

    ``executor``: where the trainings run, opened (default: the plan's ``--executor``, opened and
    closed here). Returns the results document. Failed runs are reported (with their log) and
    skipped; after the outputs are written, a :class:`StealthNSError` lists them.
    """
    from tqdm import tqdm

    owned = executor is None
    if executor is None:
        executor = make_executor(plan.executor)
        executor.open()
    started = time.time()
    # the bar is drawn on a terminal only; elsewhere (a log file) the per-run lines tell the progress
    bar = tqdm(total=len(plan.runs), unit="run", desc="bench attack", dynamic_ncols=True, disable=None)
    bench = _Bench(plan, executor, bar, started)
    outcomes = executor.run(bench.jobs(), bench)
    try:
        for outcome in outcomes:
            bench.finish(outcome)
    except KeyboardInterrupt:
        bar.close()
        outcomes.close()  # Ray: the running tasks are cancelled (their ns-train stopped)
        unfinished = "the unfinished run is" if executor.sequential else "unfinished runs are"
        print(
            "interrupted: finished runs are kept; run the same command again to resume "
            f"({unfinished} retrained)",
            file=sys.stderr,
        )
        raise
    finally:
        outcomes.close()
        if owned:
            executor.close()
    bar.close()
    results = bench.write(complete=not bench.failures)
    if bench.failures:
        raise StealthNSError(
            f"{len(bench.failures)} of {len(plan.runs)} runs failed ({', '.join(bench.failures)}); their "
            f"numbers are n/a in {plan.output / 'tables.md'}; the logs are named above. Run the same command "
            "again to retry them (finished runs and their metrics are reused)"
        )
    return results


def _attach_metrics(
    plan: Plan, p: PlannedRun, record: TrainRecord, records: dict[str, TrainRecord], entry: dict, bar: Any
) -> str:
    """Compare ``p`` with its scene's clean run into ``entry``; returns a short note for the log line."""
    clean = plan.get(clean_run(p.run.scene).key)
    clean_rec = records.get(clean.key)
    if clean_rec is None:
        entry["metrics_error"] = f"the clean run {clean.key} failed"
        return f"; no metrics: the clean run {clean.key} failed"
    bar.set_postfix_str(f"{p.key} metrics")
    try:
        metrics, seconds, cached = cached_pair_metrics(p, record, clean, clean_rec)
    except Exception as err:  # one failed comparison must not stop the benchmark
        log = p.spec.run_dir / METRICS_LOG
        entry["metrics_error"] = f"{type(err).__name__}: {err} (traceback in {log})"
        return f"; metrics FAILED: {type(err).__name__}: {err} (see {log})"
    entry.update(metrics=metrics, metrics_seconds=seconds, metrics_cached=cached)
    ill, drop = metrics.get("v_illusory_psnr"), metrics.get("v_test_drop")
    note = f"; V-illusory {fmt_value(ill, 2)} dB, V-test drop {fmt_value(drop, 2)} dB"
    return note + (", attack succeeds" if metrics.get("attack_success") else ", attack fails")
