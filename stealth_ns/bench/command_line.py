"""``stealth-ns bench raster``, ``bench train``, ``bench attack`` and ``bench scan``: their options, as tyro
parses them, checked before torch and nerfstudio load where that can be done, and the commands."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import tyro

from stealth_ns.bench.scan_runs import PlyFrame
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.output_folder import check_file_writable
from stealth_ns.scan.config import ScanConfig


@dataclass
class BenchRaster:
    """Time forward and forward+backward of the compiled and pure-PyTorch CPU rasterizers."""

    json: Path | None = None
    """Also write the figures to this JSON file."""
    quick: bool = False
    """Only the smallest case, 3 timed runs (the reference: 1): a smoke run, not for reporting."""
    threads: int | None = None
    """Torch/OpenMP threads (default: torch's default, the number of cores)."""

    def main(self) -> None:
        from stealth_ns.raster.bench import DEFAULT_CASES, run_raster_benchmark

        if self.json is not None:
            check_file_writable(self.json, "--json")
        kwargs = {"cases": DEFAULT_CASES[:1], "repeats": 3, "reference_repeats": 1} if self.quick else {}
        run_raster_benchmark(json_path=self.json, threads=self.threads, **kwargs)


@dataclass
class BenchTrain:
    """Time training steps of the default orbit run (or --data), split into phases."""

    data: Path | None = None
    """A nerfstudio-data, COLMAP or Blender dataset (default: the generated orbit scene, seed --seed); one
    without seed points gets them triangulated first, as bench attack does."""
    method: Literal["stealth-splat-lite", "stealth-splat"] = "stealth-splat-lite"
    """The method, trained with its default attack as ns-train runs it."""
    warmup: int = 1000
    """Steps trained before timing starts (1000: the orbit run has grown to ~80k of its ~90k
    Gaussians and uses all SH degrees; densification and opacity resets still happen)."""
    steps: int = 200
    """Steps timed after the warm-up."""
    seed: int = 0
    threads: int | None = None
    """Torch/OpenMP threads (default: torch's default, the number of cores)."""
    json: Path | None = None
    """Also write the figures to this JSON file (keys median_step_ms, phases_ms, ...)."""
    preset: str = "orbit"
    """Without --data: the generated scene (stealth-ns make-scene --preset; object: the 360-degree
    object-centred Blender scene, its seed points triangulated)."""
    resolution: str | None = None
    """Without --data: the generated scene's WIDTHxHEIGHT (default: the preset's), e.g. 1008x756."""
    attack: bool = True
    """False: time the clean run (--pipeline.attack.enabled False) instead."""

    def main(self) -> None:
        from stealth_ns.scene_generator import PRESETS, parse_resolution

        if self.json is not None:
            check_file_writable(self.json, "--json")
        if self.data is not None and not self.data.exists():
            raise StealthNSError(f"--data {self.data} does not exist")
        if self.data is not None and (self.preset != "orbit" or self.resolution is not None):
            raise StealthNSError("--preset and --resolution choose a generated scene: not with --data")
        if self.preset not in PRESETS:
            raise StealthNSError(f"--preset {self.preset!r}: choose one of {', '.join(PRESETS)}")
        if self.resolution is not None:
            parse_resolution(self.resolution)  # a malformed one before the scene is made
        from stealth_ns.bench.train_step import run_train_benchmark  # torch and nerfstudio: seconds

        result = run_train_benchmark(
            data=self.data,
            method=self.method,
            warmup=self.warmup,
            steps=self.steps,
            seed=self.seed,
            threads=self.threads,
            json_path=self.json,
            preset=self.preset,
            resolution=self.resolution,
            attack=self.attack,
        )
        print(result.table())


@dataclass
class BenchAttack:
    """Reproduce the paper's Tables 1-6 on generated scenes and dataset folders: train, write the tables."""

    output: Path = Path("bench-attack-output")
    """Folder for the scenes, the runs (reused when finished), tables.md and results.json."""
    tables: tuple[str, ...] = ("1", "2", "3", "4", "5", "6")
    """Paper tables to reproduce: 1 single view, 2 Easy/Median/Hard, 3 multi-view, 4 KDE bandwidth,
    5 noise schedule, 6 attack components (with ASR); and this project's stealth tables (asked for by
    number or with all): 7 stealth-aware variants, 8 the attack's knobs one at a time, 9 adaptive attacks
    against camera-proximity and the scan."""
    scenes: tuple[str, ...] = ("orbit", "forward", "facing", "fox=../shared/data/fox")
    """Generated presets (orbit: 360°, Mip-NeRF 360-like; forward: free trajectory, Free-like;
    facing: forward-facing, LLFF-like) and dataset folders as NAME=PATH (nerfstudio-data, COLMAP
    sparse/0 + images, or Blender; used in place, never written; seed points triangulated into
    OUTPUT/scenes/NAME when the dataset has none). captures: the phone captures beer, bird and cup of
    ../shared/data/captures at their own resolution (or one of them by name). Folders join Tables 1-2
    with their KDE views. A folder of this default that is absent is skipped with a note; one you
    name is required."""
    iterations: int | None = None
    """Training iterations of every run (default: the method's, 3000 for stealth-splat-lite)."""
    method: str = "stealth-splat-lite"
    """stealth-splat-lite (small scenes, CPU) or stealth-splat."""
    seed: int = 0
    """Seed of the scenes, the training and the attack's noise."""
    dry_run: bool = False
    """Only list the runs: which would train, which are reused, with their ns-train commands."""
    attacks: tuple[Literal["in-loop", "data-only", "ipa"], ...] = ("in-loop", "data-only", "ipa")
    """Attacks whose rows Tables 1-3 show: in-loop (ns-train stealth-splat*), data-only (a poisoned dataset
    from stealth-ns poison-dataset, plain victim) and ipa (IPA-Splat, stealth-ns ipa-poison: the attacker
    trains once more per row). docs/design/baselines.md."""
    only: tuple[str, ...] = ()
    """Train only the runs whose name (SCENE/RUN, e.g. fox/views-2 or st-support-3) contains one of these,
    with their scenes' clean baselines; the tables' other cells read n/a."""
    defend: bool = False
    """Also Table D, stealth under defences: stealth-ns defend on each scene's Table 1 poisoned run into
    OUTPUT/defend/SCENE (adds Table 1; its input-filter defence retrains each of those runs once;
    docs/design/defences.md)."""
    executor: Annotated[str, tyro.conf.arg(metavar="{local,ray}")] = "local"
    """Where the trainings run: local (one after another on this machine) or ray (Ray tasks on a
    cluster, in parallel; needs pip install 'stealth-ns[cluster]' and run folders on a file system
    every node sees at the same path; docs/design/cluster.md)."""
    ray_address: Annotated[
        str | None, tyro.conf.arg(metavar="ADDR", help_behavior_hint="(default: RAY_ADDRESS, else local)")
    ] = None
    """With --executor ray: HOST:PORT of the Ray head (port 6379 by default), ray://HOST:PORT (Ray
    Client), auto (the cluster started on this machine with `ray start`) or local (a new Ray
    instance on this machine, stopped at the end)."""
    ray_cpus_per_run: Annotated[
        float | None, tyro.conf.arg(metavar="N", help_behavior_hint="(default: 1)")
    ] = None
    """With --executor ray: CPUs each training reserves, also its CPU threads."""
    ray_gpus_per_run: Annotated[
        float | None,
        tyro.conf.arg(metavar="G", help_behavior_hint="(default: 1 if the cluster has GPUs, else 0)"),
    ] = None
    """With --executor ray: GPUs each training reserves (0.5: two trainings share one)."""
    ray_max_retries: Annotated[
        int | None,
        tyro.conf.arg(metavar="N", help_behavior_hint="(default: 3)"),
    ] = None
    """With --executor ray: resubmissions of a run whose Ray worker or node was lost."""
    ray_train_retries: Annotated[
        int | None, tyro.conf.arg(metavar="N", help_behavior_hint="(default: 1)")
    ] = None
    """With --executor ray: retries of a training that failed (ns-train exited non-zero)."""

    def main(self) -> None:
        from stealth_ns.bench.attack import run_bench
        from stealth_ns.bench.executors import ExecutorOptions
        from stealth_ns.method_configs.attack_experiments import DEFAULT_SCENES

        run_bench(
            output=self.output,
            tables=self.tables,
            # the default list (None) skips its absent folders; scenes given explicitly must exist
            scenes=None if tuple(self.scenes) == DEFAULT_SCENES else self.scenes,
            method=self.method,
            iterations=self.iterations,
            seed=self.seed,
            dry_run=self.dry_run,
            defend=self.defend,
            attacks=self.attacks,
            only=self.only,
            executor=ExecutorOptions(
                name=self.executor,
                address=self.ray_address,
                cpus_per_run=self.ray_cpus_per_run,
                gpus_per_run=self.ray_gpus_per_run,
                max_retries=self.ray_max_retries,
                train_retries=self.ray_train_retries,
            ),
        )


@dataclass
class BenchScan:
    """Scan every run of a bench attack folder: the verdict against what each run is (docs/design/scan.md)."""

    runs: Path
    """A `stealth-ns bench attack` output folder (or its results.json): the runs to scan."""
    output: Path = Path("bench-scan-output")
    """Folder for scan.md (confusion table, AUROC, every run) and scan-results.json."""
    only: tuple[str, ...] = ()
    """Scan only the runs whose name (SCENE/RUN, e.g. orbit/clean) contains one of these."""
    as_ply: bool = False
    """Scan each run as another trainer's model: written as a 3DGS PLY in --ply-frame, without the
    poison tag (OUTPUT/plys/), then scanned with --frame auto."""
    ply_frame: PlyFrame = "dataset"
    """With --as-ply: the frame the PLYs are written in: the dataset's own (official 3DGS, OpenSplat by
    default), OpenSplat's --center, or gsplat simple_trainer's default normalised frame (docs/design/scan.md)."""  # noqa: E501
    fit_first: tuple[str, ...] = ()
    """Scenes on which the held-out calibration first chooses the region threshold (judged on the
    other scenes, then the halves swap). Default: every other scene, in the order of results.json."""
    options: Annotated[ScanConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=ScanConfig)

    def main(self) -> None:
        from stealth_ns.bench.scan_runs import check_arguments, check_scenes

        runs = check_arguments(self.runs, self.output, self.options, self.only, self.as_ply)  # before torch
        check_scenes(runs, self.fit_first, "--fit-first")
        from stealth_ns.bench.scan_table import TABLE_FILE, run_bench_scan

        run_bench_scan(
            self.runs, self.output, self.options, self.only, self.as_ply, self.fit_first, self.ply_frame
        )
        print((self.output / TABLE_FILE).read_text(encoding="utf-8"))
