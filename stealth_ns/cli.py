"""`stealth-ns` console script: tyro subcommands.

Every subcommand raises :class:`StealthNSError` for bad input; ``run`` prints it (and a write the
environment refused) as one line (``stealth-ns: error: ...``), exit status 2, never a traceback.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import tyro

from stealth_ns.attack.config import AttackConfig
from stealth_ns.bench.scan_runs import PlyFrame
from stealth_ns.defences.config import DefendConfig
from stealth_ns.difficulty.rank import RankViews
from stealth_ns.foundation import deferred_compile
from stealth_ns.foundation.errors import StealthNSError, environment_error
from stealth_ns.foundation.output_folder import check_file_writable
from stealth_ns.poisoned_datasets.config import IPAConfig, data_only_attack_defaults
from stealth_ns.scan.config import ScanConfig


@dataclass
class MakeScene:
    """Generate a procedural scene (images, poses, depth; seed points except for Blender format)."""

    output: Path
    """Folder to write (created; must be empty unless --overwrite)."""
    preset: Literal["orbit", "forward", "facing", "object"] = "orbit"
    """orbit: inward-facing 360 capture (Mip-NeRF 360 like), nerfstudio-data format;
    forward: free forward trajectory (Free like), nerfstudio-data format;
    facing: forward-facing hand-held capture of a cluttered scene (LLFF like), nerfstudio-data format;
    object: 1-3 objects on a transparent background seen from the upper hemisphere (NeRF-synthetic
    like), Blender format (train with blender-data)."""
    resolution: str | None = None
    """Image size as WIDTHxHEIGHT in pixels (default: 128x96; 128x128 for object)."""
    views: int | None = None
    """Number of views, at least 8 (default: 60 orbit, 48 forward, 24 facing, 150 object = 100 train
    + 25 val + 25 test)."""
    seed: int = 0
    """Random seed: the same seed gives byte-identical files."""
    overwrite: bool = False
    """Replace the contents of a non-empty output folder."""

    def main(self) -> None:
        from stealth_ns.scene_generator import make_scene

        summary = make_scene(
            preset=self.preset,
            output=self.output,
            resolution=self.resolution,
            views=self.views,
            seed=self.seed,
            overwrite=self.overwrite,
        )
        print(summary)


@dataclass
class Demo:
    """Generate the facing scene, train stealth-splat-lite on it clean and poisoned, and print the report."""

    output: Path = Path("demo-output")
    """Folder for the scene, the runs and the logs."""
    iterations: int | None = None
    """Training iterations (default: the method's 3000)."""
    seed: int = 0
    """Scene and training seed."""

    def main(self) -> None:
        from stealth_ns.demo import run_demo

        print(run_demo(self.output, self.iterations, self.seed))


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
class Report:
    """Compare a poisoned run with a clean run of the same scene: report.json, report.html, PNGs."""

    poisoned: Path
    """config.yml (or run folder) of the attacked run, or a 3DGS PLY of a victim trained elsewhere
    (with --poisoned-data)."""
    clean: Path
    """config.yml (or run folder) of a clean run of the same scene (--pipeline.attack.enabled False), or a
    3DGS PLY (with --clean-data)."""
    output: Path = Path("stealth-report")
    """Folder to write report.json, report.html, the figures and images/."""
    defend: Path | None = None
    """Output folder of `stealth-ns defend --run POISONED`: adds a "Defences" section to report.html."""
    poisoned_data: Path | None = None
    """The dataset a --poisoned PLY was trained on (for a victim of poison-dataset: the poisoned copy)."""
    clean_data: Path | None = None
    """The dataset a --clean PLY was trained on."""
    stealth: bool = True
    """Measure the poisoned run's stealth: every post-hoc defence's AUROC, the V-illusory the strongest
    leaves at <= 0.5 dB of V-test, stealthy success (seconds at the demo's scale; --no-stealth skips it)."""

    def main(self) -> None:
        from stealth_ns.report.arguments import check_arguments

        check_arguments(self.poisoned, self.clean, self.output, self.defend)  # before torch loads
        from stealth_ns.report.write import summary_lines, write_report

        data = (self.poisoned_data, self.clean_data)
        report = write_report(self.poisoned, self.clean, self.output, self.defend, self.stealth, *data)
        print("\n".join(summary_lines(report, self.output)))


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
class SeedPoints:
    """Triangulate seed points (sparse_pc.ply) for a known-pose capture from its images and poses."""

    data: Path
    """nerfstudio-data folder (transforms.json), a transforms JSON file, or a Blender-format folder
    (transforms_train.json)."""
    output: Path | None = None
    """Folder for transforms.json + sparse_pc.ply, image paths pointing back to DATA (for a read-only
    dataset). Default: write sparse_pc.ply and a copy transforms_seeded.json into DATA."""
    overwrite: bool = False
    """Without --output: update DATA's transforms file in place (ply_file_path) and replace its
    sparse_pc.ply. With --output: replace OUTPUT's transforms.json and sparse_pc.ply."""
    max_points: int | None = None
    """Keep at most this many points (a random subset drawn with --seed)."""
    min_views: int = 3
    """Keep points seen in at least this many images (2 gives more, noisier points)."""
    max_error: float = 2.0
    """Keep points whose mean reprojection error is at most this many pixels."""
    seed: int = 0
    """Seed of COLMAP's RANSAC and of the --max-points subset: the same seed gives the same PLY."""

    def main(self) -> None:
        from stealth_ns.datasets.seed_points import make_seed_points

        summary = make_seed_points(
            data=self.data,
            output=self.output,
            overwrite=self.overwrite,
            max_points=self.max_points,
            seed=self.seed,
            min_views=self.min_views,
            max_error=self.max_error,
        )
        print(summary)


@dataclass
class CheckData:
    """Check a nerfstudio-data, COLMAP or Blender dataset (files, images, poses, intrinsics, seed points)."""

    data: Path
    """nerfstudio-data folder (transforms.json), a transforms JSON file, a COLMAP folder (sparse/0,
    images/) or a Blender folder (transforms_train/val/test.json)."""

    def main(self) -> None:
        from stealth_ns.datasets.check import check_dataset

        try:
            summary = check_dataset(self.data)
        except StealthNSError as err:  # a broken dataset is this command's "no" answer: exit 1
            print(f"stealth-ns: error: {err}", file=sys.stderr)
            sys.exit(1)
        print(summary)


@dataclass
class Defend:
    """Run defences against an attacked run: can the poison be found, and what does removing it cost?"""

    run: Path
    """config.yml (or run folder) of the attacked run."""
    output: Path = Path("stealth-defend")
    """Folder for defend.json, defend.md, the figures, the pruned runs (pruned/) and the retrained
    run (input-filter/)."""
    clean: Path | None = None
    """config.yml of a clean run of the same scene: its V-test and V-illusory as reference."""
    options: Annotated[DefendConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=DefendConfig)

    def main(self) -> None:
        from stealth_ns.defence_eval.arguments import check_arguments

        check_arguments(self.run, self.output, self.options, self.clean)  # before torch and nerfstudio load
        from stealth_ns.defence_eval.command import run_defend

        run_defend(self.run, self.output, self.options, self.clean)
        print(f"\nwrote {self.output / 'defend.json'}, {self.output / 'defend.md'} and the figures")
        print((self.output / "defend.md").read_text())


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
    default), OpenSplat's --center, or gsplat simple_trainer's default normalised frame (docs/design/scan.md)."""
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


@dataclass
class Scan:
    """Look for poison in a trained 3DGS model from any trainer, no ground truth: a verdict and the views."""

    model: Path
    """The model: a 3DGS PLY (official 3DGS, gsplat, OpenSplat, ns-export gaussian-splat), a
    nerfstudio run's config.yml (stealth-splat, splatfacto) or an official 3DGS output folder
    (cameras.json, point_cloud/iteration_*/)."""
    data: Path | None = None
    """The dataset the model was trained on (nerfstudio-data, COLMAP or Blender): its training cameras
    and images. Needed for a PLY; a run's own dataset by default; for an official 3DGS output folder,
    its cfg_args' source_path, else none (scanned on its cameras.json alone)."""
    output: Path = Path("stealth-scan")
    """Folder for scan.json, scan.html, the images and the cleaned model (cleaned.ply, cleaned/)."""
    options: Annotated[ScanConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=ScanConfig)

    def main(self) -> None:
        from stealth_ns.scan.arguments import check_arguments

        check_arguments(self.model, self.data, self.output, self.options)  # before torch and nerfstudio load
        from stealth_ns.scan.command import run_scan, summary_lines

        doc = run_scan(self.model, self.data, self.output, self.options)
        print("\n".join(summary_lines(doc, self.output)))


@dataclass
class PoisonDataset:
    """Write a poisoned copy of a dataset (the data-only StealthAttack) that any 3DGS trainer can consume."""

    data: Path
    """nerfstudio-data (transforms.json) or COLMAP (sparse/0 + images/) dataset folder; never written."""
    output: Path
    """Folder for the poisoned copy (new or empty; its record goes to OUTPUT/attack)."""
    method: Literal["stealth-splat-lite", "stealth-splat"] = "stealth-splat-lite"
    """Method whose data loading and seed-point initialisation place the poison (as ns-train would)."""
    overwrite: bool = False
    """Replace OUTPUT when it is an earlier poisoned copy (never anything else)."""
    attack: Annotated[AttackConfig, tyro.conf.OmitArgPrefixes] = field(
        default_factory=data_only_attack_defaults
    )

    def main(self) -> None:
        from stealth_ns.attack.options import STEALTH_NS
        from stealth_ns.attack.validation import validate_attack_config

        if not self.attack.enabled:
            raise StealthNSError(
                "--enabled False: poison-dataset always writes the attack (copy the folder instead)"
            )
        # at once, not after torch and nerfstudio load (~10 s)
        validate_attack_config(self.attack, spelling=STEALTH_NS)
        from stealth_ns.poisoned_datasets.data_only import poison_dataset

        # --seed (the attack's) also seeds the set-up, as ns-train's --machine.seed would
        summary = poison_dataset(
            self.data, self.output, self.attack, self.method, self.attack.seed, self.overwrite
        )
        print(summary)


@dataclass
class IpaPoison:
    """Write an IPA-Splat poisoned copy of a dataset (the paper's baseline: IPA-NeRF's attack on 3DGS)."""

    data: Path
    """nerfstudio-data or COLMAP dataset folder; never written."""
    output: Path
    """Folder for the poisoned copy (new or empty); the record and the attacker's run go to OUTPUT/attack."""
    illusion: str = "astronaut"
    """The illusion at the backdoor view(s), as --pipeline.attack.illusion (a built-in or an image path)."""
    illusion_mask: Path | None = None
    """Mask image for an RGB illusion, as --pipeline.attack.illusion-mask."""
    illusion_center: tuple[float, float] = (0.5, 0.5)
    """Where the illusion's centre sits in the backdoor view, fractions of (width, height)."""
    illusion_scale: float = 0.4
    """Illusion height as a fraction of the view's height."""
    views: tuple[str, ...] = ()
    """Backdoor training views by index or image name; empty = the median training frame."""
    multi_view: int = 1
    """1..4 backdoor views at 0/90/180/270 degrees about the scene's up axis (as the StealthAttack option)."""
    method: Literal["stealth-splat-lite", "stealth-splat"] = "stealth-splat-lite"
    """The attacker's training method (attack off)."""
    iterations: int | None = None
    """Training steps of the attacker's run (default: the method's)."""
    seed: int = 0
    """Random seed of the attacker's training (--machine.seed)."""
    overwrite: bool = False
    """Replace OUTPUT when it is an earlier poisoned copy (never anything else)."""
    ipa: Annotated[IPAConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=IPAConfig)

    def main(self) -> None:
        from stealth_ns.attack.options import STEALTH_NS
        from stealth_ns.attack.validation import validate_attack_config

        attack = AttackConfig(
            illusion=self.illusion,
            illusion_mask=self.illusion_mask,
            illusion_center=self.illusion_center,
            illusion_scale=self.illusion_scale,
            views=self.views,
            multi_view=self.multi_view,
            gt_replacement=False,
            density_guided=False,
            view_noise=False,
            seed=self.seed,
        )
        validate_attack_config(attack, spelling=STEALTH_NS)
        if self.iterations is not None and self.iterations < 1:
            raise StealthNSError(f"--iterations must be a positive integer, got {self.iterations}")
        self.ipa.validate()  # these at once, not after torch and nerfstudio load (~10 s)
        from stealth_ns.poisoned_datasets.ipa_splat import ipa_poison

        summary = ipa_poison(
            self.data, self.output, attack, self.ipa, self.method, self.seed, self.iterations, self.overwrite
        )
        print(summary)


# command words -> dataclass; each dataclass has a ``main()``. Kept as a plain table (not a
# tyro union) so that every command, nested ones included, gets its own --help.
COMMANDS: dict[str, type] = {
    "make-scene": MakeScene,
    "demo": Demo,
    "report": Report,
    "bench raster": BenchRaster,
    "bench attack": BenchAttack,
    "bench train": BenchTrain,
    "bench scan": BenchScan,
    "rank-views": RankViews,
    "seed-points": SeedPoints,
    "check-data": CheckData,
    "defend": Defend,
    "scan": Scan,
    "poison-dataset": PoisonDataset,
    "ipa-poison": IpaPoison,
}


def _usage() -> str:
    lines = [
        "usage: stealth-ns COMMAND [OPTIONS]   (stealth-ns COMMAND --help for its options)",
        "",
        "commands:",
    ]
    for name, cls in COMMANDS.items():
        doc = (cls.__doc__ or "").strip().splitlines()[0]
        lines.append(f"  {name:<16} {doc}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    words = []
    while argv and not argv[0].startswith("-") and " ".join([*words, argv[0]]) in _command_prefixes():
        words.append(argv.pop(0))
    name = " ".join(words)
    if name not in COMMANDS:
        if not words and argv and argv[0] in ("-h", "--help"):
            print(_usage())
            return
        unknown = " ".join(words) or (argv[0] if argv else "")
        raise StealthNSError(
            f"unknown command {unknown!r}; commands: {', '.join(COMMANDS)}"
            if unknown
            else f"no command given; commands: {', '.join(COMMANDS)}"
        )
    tyro.cli(COMMANDS[name], args=argv, prog=f"stealth-ns {name}").main()


def _command_prefixes() -> set[str]:
    prefixes = set()
    for name in COMMANDS:
        parts = name.split()
        prefixes.update(" ".join(parts[: i + 1]) for i in range(len(parts)))
    return prefixes


def run(argv: list[str] | None = None) -> int:
    """The exit status of ``stealth-ns ARGV``: 0; 2 after one line (bad input, a refused write); 130."""
    deferred_compile.install()
    try:
        main(argv)
    except (StealthNSError, OSError) as err:  # OSError: a write the environment refused (full disk)
        line = err if isinstance(err, StealthNSError) else environment_error(err)
        if line is None:
            raise
        print(f"stealth-ns: error: {line}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("stealth-ns: interrupted", file=sys.stderr)
        return 130
    return 0


def entrypoint() -> None:
    if status := run():
        sys.exit(status)


if __name__ == "__main__":
    entrypoint()
