"""``stealth-ns bench attack``: plan, make the scenes, execute, add Table D (:mod:`stealth_ns.bench`)."""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from stealth_ns.bench.execute import execute
from stealth_ns.bench.executors import Executor, ExecutorOptions, make_executor
from stealth_ns.bench.plan import Plan, bench_plan, parse_tables
from stealth_ns.bench.poisoned_copies import ensure_copies
from stealth_ns.bench.results import write_results
from stealth_ns.datasets.generated import ensure_scene
from stealth_ns.datasets.seeded import ensure_seed_points
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.json_io import json_safe
from stealth_ns.method_configs.attack_experiments import (
    ATTACKS,
    clean_run,
    get_run,
    single_view_run,
)
from stealth_ns.runs.training import (
    finished_record,
)

DEFAULT_OUTPUT = Path("bench-attack-output")


def run_bench(
    output: Path = DEFAULT_OUTPUT,
    tables: Sequence[str | int] | None = None,
    scenes: Sequence[str] | None = None,
    method: str = "stealth-splat-lite",
    iterations: int | None = None,
    seed: int = 0,
    dry_run: bool = False,
    scene_options: dict[str, Any] | None = None,
    executor: ExecutorOptions | None = None,
    defend: bool = False,
    attacks: Sequence[str] = ATTACKS,
    only: Sequence[str] = (),
) -> Plan | dict[str, Any]:
    """``stealth-ns bench attack``: the plan (``dry_run``) or the results document.

    ``executor``: where the trainings run (``--executor`` and its options; default local).
    ``defend``: also Table D (:mod:`stealth_ns.bench.defence_table`), which needs Table 1's runs.
    ``only``: plan only the runs whose ``SCENE/RUN`` contains one of these (``--only``).
    """
    options = (executor or ExecutorOptions()).checked()
    if defend:
        tables = (*parse_tables(tables), 1)
    # without --dry-run this first plan only checks the input: the views are ranked below
    plan = bench_plan(
        output,
        tables,
        scenes,
        method,
        iterations,
        seed,
        scene_options,
        rank_views=dry_run,
        attacks=attacks,
        only=only,
    )
    plan.executor, plan.defend = options, defend
    for line in plan.skipped_scenes:
        print(line, flush=True)
    if dry_run:
        print(plan.describe(dry_run=True))
        return plan
    runner = make_executor(options)
    runner.open()  # before anything is made: a cluster that cannot be reached stops the bench here
    try:
        return _run_plan(plan, runner, tables, scenes, method, seed, scene_options)
    finally:
        runner.close()


def _run_plan(
    plan: Plan,
    runner: Executor,
    tables: Sequence[str | int] | None,
    scenes: Sequence[str] | None,
    method: str,
    seed: int,
    scene_options: dict[str, Any] | None,
) -> dict[str, Any]:
    """Make the scenes (presets, seed points), plan again with them, and execute the plan."""
    output = plan.output
    failed: dict[str, str] = {}
    for scene in plan.scenes:  # generate the presets, make the seed points of folders without them
        src = plan.sources[scene]
        try:
            if src.is_preset:
                ensure_scene(plan.scene_dirs[scene], scene, plan.seed, scene_options)
            elif src.triangulated:
                ensure_seed_points(plan.output, src)
        except Exception as err:  # one unusable scene must not stop the others
            what = "generating the scene" if src.is_preset else "making its seed points"
            failed[scene] = f"{what} failed: " + (
                str(err) if isinstance(err, StealthNSError) else f"{type(err).__name__}: {err}"
            )
            print(f"FAILED {scene}: {failed[scene]}", file=sys.stderr, flush=True)
    options, defend = plan.executor, plan.defend
    attacks = plan.attacks
    plan = bench_plan(
        output,
        tables,
        scenes,
        method,
        plan.iterations,
        seed,
        scene_options,
        write_cache=True,
        attacks=attacks,
        only=plan.only,
    )
    plan.executor, plan.defend = options, defend
    plan.scene_errors.update(failed)
    print(plan.describe(dry_run=False), flush=True)
    print(flush=True)
    # no copy for a scene that cannot run (generation, seed points or its KDE ranking failed)
    copies = {
        p.key: p.poison for p in plan.runs if p.poison is not None and p.run.scene not in plan.scene_errors
    }
    plan.run_errors.update(ensure_copies({k: job for k, job in copies.items() if job is not None}))
    failure = None
    try:
        results = execute(plan, runner)
    except StealthNSError as err:  # the outputs are written; Table D still covers the scenes that trained
        failure, results = err, json.loads((plan.output / "results.json").read_text())
    if plan.defend:
        results = add_defence_table(plan, results)
    print(f"\nwrote {plan.output / 'tables.md'} and {plan.output / 'results.json'}")
    if failure is not None:
        raise failure
    return results


def add_defence_table(plan: Plan, results: dict[str, Any]) -> dict[str, Any]:
    """Table D over the scenes of Table 1 (``stealth-ns defend`` on each scene's Table 1 run) into
    results.json (``table_d``) and tables.md; returns the results."""
    from stealth_ns.bench.defence_table import defend_scenes

    table1 = next(t for t in plan.tables if t.number == 1)
    scenes = [s for s in plan.scenes if s in table1.scenes]
    pairs = {s: (get_run(s, single_view_run(s)).key, clean_run(s).key) for s in scenes}
    run_ids = {}
    for key in {k for pair in pairs.values() for k in pair}:
        record = finished_record(plan.get(key).spec)
        if record is not None:
            run_ids[key] = record.run_id
    results["table_d"] = json_safe(defend_scenes(scenes, results["runs"], pairs, run_ids, plan.output))
    write_results(plan.output, results)
    return results
