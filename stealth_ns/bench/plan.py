"""The plan of a benchmark: the runs the chosen tables need on the chosen scenes, deduplicated (a run
shared by several tables trains once), clean baselines first, each with its ns-train spec and what is
on disk for it; ``--dry-run`` prints it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from stealth_ns.bench.executors import ExecutorOptions
from stealth_ns.bench.poisoned_copies import PoisonJob
from stealth_ns.bench.scenes import kde_views, parse_scenes, scene_fingerprint
from stealth_ns.datasets.generated import scene_dir, scene_is_ready
from stealth_ns.datasets.seeded import read_seed_points, seeded_dir
from stealth_ns.datasets.source import SceneSource
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.method_configs.attack_experiments import (
    ATTACKS,
    KDE_LEVELS,
    PAPER_TABLES,
    TABLES,
    RunSpec,
    TableSpec,
    clean_run,
    get_run,
    get_table,
)
from stealth_ns.method_configs.registry import METHODS, method_iterations
from stealth_ns.runs.training import (
    RunStatus,
    TrainSpec,
    finished_record,
    run_status,
)


def parse_tables(values: Sequence[str | int] | None) -> tuple[int, ...]:
    """Table numbers from ``--tables`` values (``6``, ``"1,2"``, ``"all"``: every table, the stealth
    tables too); None = the paper's (:data:`PAPER_TABLES`)."""
    known = tuple(t.number for t in TABLES)
    if values is None:
        return PAPER_TABLES
    chosen: list[int] = []
    for value in values:
        for item in str(value).replace(",", " ").split():
            if item.lower() == "all":
                chosen.extend(known)
                continue
            number = int(item) if item.isdigit() else None
            if number not in known:
                raise StealthNSError(f"unknown table {item!r}; tables: {' '.join(map(str, known))}")
            chosen.append(number)
    if not chosen:
        raise StealthNSError(f"no table given; tables: {' '.join(map(str, known))}")
    return tuple(sorted(set(chosen)))


@dataclass
class PlannedRun:
    """A run of the plan: its preset, its ns-train spec and what is on disk for it."""

    run: RunSpec
    spec: TrainSpec
    status: RunStatus
    tables: tuple[int, ...]
    view: str | None = None
    """The poisoned view's image name when the KDE protocol picks it (None: the attack's default)."""
    poison: PoisonJob | None = None
    """A dataset attack's poisoned copy, which the run trains on (None: the run trains on the scene)."""

    @property
    def key(self) -> str:
        return self.run.key


@dataclass
class Plan:
    """The runs needed for some tables on some scenes, deduplicated, clean baselines first."""

    output: Path
    method: str
    iterations: int
    seed: int
    tables: tuple[TableSpec, ...]
    scenes: tuple[str, ...]
    scene_dirs: dict[str, Path]
    """The dataset each scene trains on (``--data``): a generated scene, a dataset folder, or the
    seeded copy of one (its predicted folder until the seed points are made)."""
    scene_ready: dict[str, bool]
    views: dict[str, dict[str, str]]
    runs: list[PlannedRun]
    skipped: list[str] = field(default_factory=list)
    sources: dict[str, SceneSource] = field(default_factory=dict)
    seed_points: dict[str, dict[str, Any]] = field(default_factory=dict)
    """The record of the triangulated seed points of each dataset folder that has them made."""
    skipped_scenes: list[str] = field(default_factory=list)
    """"skipping NAME: ..." for each folder of the default ``--scenes`` that is absent."""
    scene_errors: dict[str, str] = field(default_factory=dict)
    """Scenes that cannot be used (seed points or KDE views failed): their runs fail, the rest go on."""
    executor: ExecutorOptions = field(default_factory=ExecutorOptions)
    """Where the trainings run (``--executor``)."""
    defend: bool = False
    """Also Table D: ``stealth-ns defend`` on each scene's Table 1 run (``--defend``)."""
    attacks: tuple[str, ...] = ATTACKS
    """The attacks whose rows are planned (``--attacks``)."""
    only: tuple[str, ...] = ()
    """``--only``: the runs planned are those whose ``SCENE/RUN`` contains one of these (and their
    scenes' clean baselines); empty = every run of the tables."""
    run_errors: dict[str, str] = field(default_factory=dict)
    """Runs that cannot train (their poisoned dataset could not be made): they fail, the rest go on."""

    def get(self, key: str) -> PlannedRun:
        for planned in self.runs:
            if planned.key == key:
                return planned
        raise KeyError(key)

    def counts(self) -> dict[str, int]:
        return {s: sum(p.status == s for p in self.runs) for s in ("missing", "partial", "finished")}

    def _scene_lines(self, scene: str) -> list[str]:
        src = self.sources.get(scene, SceneSource(scene))
        ready = self.scene_ready[scene]
        if src.is_preset:
            return [
                f"  scene:   {scene} -> {self.scene_dirs[scene]}" + ("" if ready else "  (to be generated)")
            ]
        lines = [f"  scene:   {scene} -> {src.path}  ({src.describe()})"]
        if src.triangulated:
            record = self.seed_points.get(scene)
            state = (
                f"done: {record['n_points']} points, reused; trains on {self.scene_dirs[scene]}"
                if record
                else "to be made first"
            )
            lines.append(
                f"           seed points: triangulated into {seeded_dir(self.output, scene)}  ({state})"
            )
        return lines

    def describe(self, dry_run: bool) -> str:
        """The plan as text: settings, then one entry per run (what happens to it, its ns-train command)."""
        lines = ["stealth-ns bench attack" + (" --dry-run: nothing is trained or written" if dry_run else "")]
        lines.append(f"  output:  {self.output}  (tables.md, results.json; runs under runs/)")
        lines.append(f"  method:  {self.method}, {self.iterations} iterations, seed {self.seed}")
        lines.append("  tables:  " + "; ".join(f"{t.number} {t.title}" for t in self.tables))
        lines.append(f"  executor: {self.executor.describe()}")
        if self.only:
            lines.append(
                f"  only:    runs whose name contains {' or '.join(self.only)}, with their clean baselines"
            )
        if self.defend:
            lines.append(
                "  Table D: stealth-ns defend on each scene's Table 1 poisoned run after training "
                "(into OUTPUT/defend/SCENE; its input-filter defence retrains that run once)"
            )
        for scene in self.scenes:
            lines += self._scene_lines(scene)
        lines += [f"  note:    {note}" for note in self.skipped]
        lines += [f"  error:   {scene}: {err} (its runs fail)" for scene, err in self.scene_errors.items()]
        c = self.counts()
        lines.append("")
        lines.append(
            f"{len(self.runs)} runs: {c['missing']} to train, {c['partial']} unfinished on disk (deleted and "
            f"retrained), {c['finished']} finished (reused)"
        )
        todo = c["missing"] + c["partial"]
        done_seconds = [
            rec.seconds for p in self.runs if p.status == "finished" and (rec := finished_record(p.spec))
        ]
        if todo and done_seconds:
            mean = sum(done_seconds) / len(done_seconds)
            lines.append(
                f"estimate: {todo} x {mean / 60:.1f} min (mean of the finished runs) = "
                f"{todo * mean / 60:.0f} min of training"
            )
        action = {"missing": "train", "partial": "retrain", "finished": "reuse"}
        for p in self.runs:
            tables = ", ".join(map(str, p.tables))
            view = f"; poisoned view {p.view}" if p.view else ""
            lines.append("")
            lines.append(f"  [{action[p.status]:<7}] {p.key:<22} {p.run.label} (tables {tables}{view})")
            if p.status == "finished":
                lines.append(f"            {p.spec.run_dir}")
            else:
                if p.poison is not None:
                    made = "reused" if p.poison.ready() else "made first"
                    lines.append(f"            poisoned dataset ({made}): {p.poison.display_command()}")
                lines.append(f"            {p.spec.display_command()}")
        return "\n".join(lines)


def bench_plan(
    output: Path,
    tables: Sequence[str | int] | None = None,
    scenes: Sequence[str] | None = None,
    method: str = "stealth-splat-lite",
    iterations: int | None = None,
    seed: int = 0,
    scene_options: dict[str, Any] | None = None,
    write_cache: bool = False,
    rank_views: bool = True,
    attacks: Sequence[str] = ATTACKS,
    only: Sequence[str] = (),
) -> Plan:
    """Plan the runs of ``tables`` on ``scenes`` (bad input: :class:`StealthNSError`); with ``only``,
    those of them whose ``SCENE/RUN`` contains one of its strings.

    Looks at the disk (which runs are finished, which scenes exist, which dataset folders have
    their seed points made) but writes nothing unless ``write_cache`` (the KDE view cache). Runs
    whose poisoned view comes from the KDE protocol get a placeholder view while their scene
    does not exist yet (or has no seed points yet), or without ``rank_views``.
    """
    numbers = parse_tables(tables)
    sources, skipped_scenes = parse_scenes(scenes)
    chosen_scenes = tuple(src.name for src in sources)
    iterations = _checked_run_settings(method, seed, iterations)
    output = Path(output).expanduser().absolute()
    attacks = _checked_attacks(attacks)
    table_specs, skipped, uses = _table_runs(numbers, chosen_scenes, attacks)
    uses = _only(uses, tuple(only))
    used_scenes = tuple(s for s in chosen_scenes if any(k.startswith(f"{s}/") for k in uses))
    for scene in used_scenes:  # a scene's clean run serves every table that runs on the scene
        numbers_on_scene = {n for key, ns in uses.items() if key.startswith(f"{scene}/") for n in ns}
        uses.setdefault(clean_run(scene).key, []).extend(numbers_on_scene)

    src_of = {src.name: src for src in sources if src.name in used_scenes}
    dirs, ready, records = _scene_locations(output, src_of, seed, scene_options)
    views: dict[str, dict[str, str]] = {}
    errors: dict[str, str] = {}
    for scene in used_scenes:
        needs_kde = any(get_run(*k.split("/")).view in KDE_LEVELS for k in uses if k.startswith(f"{scene}/"))
        if rank_views and ready[scene] and needs_kde:
            src = src_of[scene]
            base = dirs[scene] if src.is_preset else output / "scenes" / scene
            cache = base.with_name(base.name + ".views.json")
            fingerprint = scene_fingerprint(dirs[scene], src, records.get(scene))
            try:
                views[scene] = kde_views(dirs[scene], cache, fingerprint, write_cache)
            except StealthNSError as err:
                errors[scene] = f"the KDE protocol cannot rank its views: {err}"

    first_use = list(uses)  # in table order, then row order: Table 6 runs in the paper's row order

    def order(key: str) -> tuple[int, bool, int]:
        run = get_run(*key.split("/"))
        return used_scenes.index(run.scene), not run.clean, first_use.index(key)

    planned = [
        _planned_run(
            get_run(*key.split("/")), src_of, dirs, views, uses[key], output, method, iterations, seed
        )
        for key in sorted(uses, key=order)
    ]
    return Plan(
        output=output,
        method=method,
        iterations=int(iterations),
        seed=int(seed),
        tables=tuple(table_specs),
        scenes=used_scenes,
        scene_dirs=dirs,
        scene_ready=ready,
        views=views,
        runs=planned,
        skipped=skipped,
        sources=src_of,
        seed_points=records,
        skipped_scenes=list(skipped_scenes),
        scene_errors=errors,
        attacks=attacks,
        only=tuple(only),
    )


def _only(uses: dict[str, list[int]], only: tuple[str, ...]) -> dict[str, list[int]]:
    """The entries of ``uses`` whose run key contains one of ``only`` (all of them when empty)."""
    if not only:
        return uses
    kept = {key: tables for key, tables in uses.items() if any(part in key for part in only)}
    if not kept:
        shown = ", ".join(list(uses)[:12]) + (", ..." if len(uses) > 12 else "")
        raise StealthNSError(f"--only {' '.join(only)} matches none of the tables' runs: {shown}")
    return kept


def _checked_attacks(attacks: Sequence[str]) -> tuple[str, ...]:
    bad = [a for a in attacks if a not in ATTACKS]
    if bad or not attacks:
        raise StealthNSError(
            f"--attacks takes some of {', '.join(ATTACKS)}, got {' '.join(attacks) or 'none'}"
        )
    return tuple(a for a in ATTACKS if a in attacks)


def _checked_run_settings(method: str, seed: int, iterations: int | None) -> int:
    """Check ``method`` and ``seed``; ``iterations`` (the method's default for None), checked."""
    if method not in METHODS:
        raise StealthNSError(f"unknown method {method!r}; methods: {', '.join(METHODS)}")
    if isinstance(seed, bool) or int(seed) != seed or seed < 0:
        raise StealthNSError(f"seed must be a non-negative integer, got {seed!r}")
    if iterations is None:
        iterations = method_iterations(method)
    if isinstance(iterations, bool) or int(iterations) != iterations or iterations < 1:
        raise StealthNSError(f"iterations must be a positive integer, got {iterations!r}")
    return iterations


def _table_runs(
    numbers: Sequence[int], scenes: tuple[str, ...], attacks: tuple[str, ...] = ATTACKS
) -> tuple[list[TableSpec], list[str], dict[str, list[int]]]:
    """The tables that run on some of ``scenes``, why the others are skipped, and for each run key
    (``SCENE/NAME``, in table order, then row order) the tables that show it."""
    table_specs: list[TableSpec] = []
    skipped: list[str] = []
    uses: dict[str, list[int]] = {}
    for number in numbers:
        on_scenes = get_table(number).for_scenes(scenes)
        table = on_scenes.for_attacks(attacks)
        keys = table.run_keys(scenes)
        if not keys:
            if on_scenes.run_keys(scenes):
                skipped.append(f"Table {number} skipped: it has no {' or '.join(attacks)} runs (--attacks)")
            else:
                skipped.append(
                    f"Table {number} skipped: it runs on {', '.join(table.scenes)}, not in --scenes"
                )
            continue
        table_specs.append(table)
        for key in keys:
            uses.setdefault(key, []).append(number)
    if not table_specs:
        raise StealthNSError("nothing to run: " + "; ".join(skipped) + f" (scenes given: {' '.join(scenes)})")
    return table_specs, skipped, uses


def _scene_locations(
    output: Path, src_of: dict[str, SceneSource], seed: int, scene_options: dict[str, Any] | None
) -> tuple[dict[str, Path], dict[str, bool], dict[str, dict[str, Any]]]:
    """Per scene: the dataset folder training reads, whether it is ready (generated, or its seed
    points made), and for a triangulated folder the record of its seed points (when made)."""
    dirs: dict[str, Path] = {}
    ready: dict[str, bool] = {}
    records: dict[str, dict[str, Any]] = {}
    for scene, src in src_of.items():
        if src.is_preset:
            dirs[scene] = scene_dir(output, scene, seed, scene_options)
            ready[scene] = scene_is_ready(dirs[scene], scene, seed, scene_options)
        elif src.triangulated:
            record = read_seed_points(output, src)
            if record is not None:
                records[scene] = record
            dirs[scene] = Path(record["dataset"]) if record else seeded_dir(output, scene)
            ready[scene] = record is not None
        else:
            assert src.path is not None
            dirs[scene], ready[scene] = src.path, True
    return dirs, ready, records


def _planned_run(
    run: RunSpec,
    src_of: dict[str, SceneSource],
    dirs: dict[str, Path],
    views: dict[str, dict[str, str]],
    tables: list[int],
    output: Path,
    method: str,
    iterations: int,
    seed: int,
) -> PlannedRun:
    """The ns-train invocation of ``run`` (shown in ``tables``): its scene's options, its attack settings
    with the KDE view (a placeholder until ranked) and the attack seed, the run folder; with its status
    on disk."""
    src = src_of[run.scene]
    attack = run.attack
    view = None
    if run.view in KDE_LEVELS:
        view = views.get(run.scene, {}).get(run.view) or f"<{run.view.upper()} view of the KDE protocol>"
        if not run.poisoning:
            attack = attack.then(views=(view,))
    if not run.clean and not run.poisoning:
        attack = attack.then(seed=int(seed))
    dataparser, dataparser_args = src.dataparser
    # a preset's folder name holds its seed and options; a folder's experiment names the training seed
    experiment = dirs[run.scene].name if src.is_preset else f"{run.scene}-seed{seed}"
    data, scene_id = dirs[run.scene], None if src.is_preset else f"{run.scene}:{src.sha256[:16]}"
    poison = None
    if run.poisoning:  # a plain victim on the poisoned copy of the scene
        folder = output / "poisoned" / f"{experiment}-{iterations}it" / run.name
        poison = PoisonJob(
            run.poisoning,
            dirs[run.scene],
            folder,
            view,
            run.poison_attack,
            method,
            seed,
            iterations,
            scene_id,
        )
        data, scene_id = folder, poison.scene_id
    spec = TrainSpec(
        scene=data,
        name=run.name,
        output_dir=output / "runs",
        experiment=f"{experiment}-{iterations}it",
        extra=src.train_args,
        attack=attack,
        method=method,
        iterations=int(iterations),
        seed=int(seed),
        dataparser=dataparser,
        dataparser_args=dataparser_args,
        scene_id=scene_id,
    )
    return PlannedRun(run, spec, run_status(spec), tuple(sorted(set(tables))), view, poison)
