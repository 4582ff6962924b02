"""``stealth-ns bench attack``: the paper's Tables 1-6 on generated scenes and dataset folders.

The presets (:mod:`stealth_ns.method_configs.attack_experiments`) say which runs each table
shows. This module resolves ``--scenes`` (generated presets, and dataset folders ``NAME=PATH``
in nerfstudio-data, COLMAP or Blender format, used in place), plans the runs of the chosen
tables and scenes (a run shared by several tables is trained once), generates the presets and
triangulates the seed points of folders without them (:mod:`stealth_ns.seed_points`, into a
seeded copy under ``OUTPUT/scenes``), trains what is missing with a progress bar across runs
(each ``ns-train``'s output goes to ``ns-train.log`` in its run folder; one after another, or as
Ray tasks on a cluster with ``--executor ray``: :mod:`stealth_ns.evaluation.executors`), reuses finished runs
and retrains interrupted ones (see :mod:`stealth_ns.evaluation.runs`), compares every poisoned
run with the clean run of its scene (:func:`stealth_ns.evaluation.report.compare_runs`, cached
as ``metrics.json`` in the poisoned run's folder) and writes ``OUTPUT/tables.md`` (markdown
shaped like the paper's tables) and ``OUTPUT/results.json`` (every number, the scenes'
sources, the environment, timings).

Layout under ``OUTPUT``: ``scenes/PRESET-seedS`` (generated once), ``scenes/NAME`` and
``scenes/NAME.seed-points.json`` (a folder's seeded copy and its record, made once),
``scenes/*.views.json`` (the KDE views), ``runs/SCENE-seedS-ITERSit/METHOD/RUN`` (one nerfstudio
run each), ``tables.md``, ``results.json``. Both outputs are rewritten after every run, so they
fill in while the benchmark runs (``"complete": false`` until the end).
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import re
import subprocess
import sys
import time
import traceback
from collections.abc import Callable, Sequence
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from stealth_ns.errors import StealthNSError
from stealth_ns.evaluation.executors import Executor, ExecutorOptions, Job, Outcome, make_executor
from stealth_ns.evaluation.poisoned_copies import PoisonJob, ensure_copies
from stealth_ns.evaluation.runs import (
    TRAIN_LOG,
    RunStatus,
    TrainRecord,
    TrainSpec,
    finished_record,
    run_status,
    train_progress,
)
from stealth_ns.fingerprint import file_sha256
from stealth_ns.json_io import json_safe, write_json_atomic
from stealth_ns.method_configs.attack_experiments import (
    ATTACKS,
    DEFAULT_SCENES,
    FOLDERS,
    KDE_LEVELS,
    PRESETS,
    SCENES,
    TABLES,
    RunSpec,
    TableSpec,
    clean_run,
    get_run,
    get_table,
    scene_kind,
    single_view_run,
)
from stealth_ns.provenance import software_and_hardware

DEFAULT_OUTPUT = Path("bench-attack-output")
#: Methods with the attack pipeline (``--pipeline.attack.*``).
METHODS: tuple[str, ...] = ("stealth-splat-lite", "stealth-splat")
METRICS_FILE = "metrics.json"
METRICS_LOG = "metrics.log"
SUCCESS_RULE = "V-illusory PSNR > 25 dB and V-test PSNR drop <= 3 dB"
NOT_IMPLEMENTED = (
    "Not implemented in stealth-ns: the paper's IPA-NeRF (Nerfacto) and IPA-NeRF (Instant-NGP) "
    "baselines (NeRF methods; no rows for them), and its datasets (Mip-NeRF 360, Tanks & Temples, "
    "Free), replaced by generated scenes and dataset folders (the real capture fox where present)."
)


# ------------------------------------------------------------------------------ scenes
FolderFormat = Literal["nerfstudio-data", "colmap", "blender"]
#: Where a COLMAP folder's model may be, relative to the folder (nerfstudio's default second).
COLMAP_DIRS: tuple[str, ...] = ("sparse/0", "colmap/sparse/0", "sparse")
#: ``OUTPUT/scenes/NAME`` + this: the record of a dataset folder's triangulated seed points.
SEED_POINTS_MARKER = ".seed-points.json"
_SCENE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")


@dataclass(frozen=True)
class SceneSource:
    """A scene of ``--scenes``: a generated preset, or a dataset folder (used in place, never written)."""

    name: str
    path: Path | None = None
    """The dataset folder (absolute); None for a preset."""
    given: str = ""
    """The folder as given on the command line."""
    format: FolderFormat | None = None
    seed_points: Literal["generated", "ply_file_path", "colmap", "triangulated"] = "generated"
    """Where the seed points come from: a preset's generator, the transforms.json's
    ``ply_file_path``, the COLMAP model's points3D, or :func:`stealth_ns.seed_points.make_seed_points`
    (a seeded copy in ``OUTPUT/scenes/NAME`` that references the folder's images)."""
    colmap_path: str | None = None
    """The COLMAP model folder, relative to ``path``."""
    files: tuple[tuple[str, str], ...] = ()
    """``(relative path, sha256)`` of the files that define the dataset (transforms.json, the COLMAP
    model); their hash :attr:`sha256` identifies it."""

    @property
    def is_preset(self) -> bool:
        return self.path is None

    @property
    def triangulated(self) -> bool:
        """The dataset has no seed points: the bench makes them first."""
        return self.seed_points == "triangulated"

    @property
    def sha256(self) -> str:
        """The content hash of the dataset: the sha256 of its transforms.json when that is the only
        file, else of the ``sha256sum``-style listing of :attr:`files`."""
        if len(self.files) == 1:
            return self.files[0][1]
        return hashlib.sha256("".join(f"{h}  {rel}\n" for rel, h in self.files).encode()).hexdigest()

    @property
    def dataparser(self) -> tuple[str, tuple[str, ...]]:
        """The nerfstudio dataparser and its options after ``--data``."""
        if self.format == "colmap":
            # --downscale-factor 1: nerfstudio would otherwise offer (interactively) to write
            # downscaled images_N folders into the dataset for images over 1600 px
            return "colmap", ("--colmap-path", str(self.colmap_path), "--downscale-factor", "1")
        return "nerfstudio-data", ()

    @property
    def train_args(self) -> tuple[str, ...]:
        """Method options the dataset needs: a Blender scene's RGBA images on white, as NeRF-synthetic."""
        return ("--pipeline.model.background-color", "white") if self.format == "blender" else ()

    def describe(self) -> str:
        if self.is_preset:
            return "generated preset"
        where = {
            "ply_file_path": "seed points from its ply_file_path",
            "colmap": f"seed points from the COLMAP model {self.colmap_path}",
            "triangulated": "no seed points",
        }[self.seed_points]
        return f"{self.format}, {where}; used in place, never written"


def _hashes(root: Path, rels: Sequence[str]) -> tuple[tuple[str, str], ...]:
    try:
        return tuple((rel, file_sha256(root / rel)) for rel in rels)
    except OSError as err:
        raise StealthNSError(f"cannot read {root}: {err.strerror or err}") from None


def inspect_folder(name: str, folder: str) -> SceneSource:
    """The :class:`SceneSource` of a dataset folder, by its format (StealthNSError if none fits).

    ``transforms.json`` -> nerfstudio-data (its ``ply_file_path`` gives the seed points, else they
    are triangulated); ``sparse/0`` (or ``colmap/sparse/0``, ``sparse``) with ``images/`` -> COLMAP;
    ``transforms_train.json`` -> Blender (converted with triangulated seed points).
    """
    path = Path(os.path.abspath(Path(folder).expanduser()))  # absolute, ".." folded
    if not path.exists():
        raise StealthNSError(f"scene {name}: {folder} not found")
    if not path.is_dir():
        raise StealthNSError(f"scene {name}: {folder} is not a folder (give the dataset folder)")
    transforms = path / "transforms.json"
    if transforms.is_file():
        try:
            meta = json.loads(transforms.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError) as err:
            raise StealthNSError(f"scene {name}: cannot read {transforms}: {err}") from None
        if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list) or not meta["frames"]:
            raise StealthNSError(
                f"scene {name}: {transforms} is not a nerfstudio transforms.json (no frames)"
            )
        ply = meta.get("ply_file_path")
        if ply and not (path / str(ply)).is_file():
            raise StealthNSError(f"scene {name}: the ply_file_path {ply!r} of {transforms} does not exist")
        seed = "ply_file_path" if ply else "triangulated"
        return SceneSource(
            name, path, folder, "nerfstudio-data", seed, files=_hashes(path, ["transforms.json"])
        )
    for rel in COLMAP_DIRS:
        model = path / rel
        if not any((model / f"cameras.{ext}").is_file() for ext in ("bin", "txt")):
            continue
        if not (path / "images").is_dir():
            raise StealthNSError(f"scene {name}: {folder} has a COLMAP model in {rel} but no images/ folder")
        if not any((model / f"points3D.{ext}").is_file() for ext in ("bin", "txt")):
            raise StealthNSError(f"scene {name}: the COLMAP model {model} has no points3D (the seed points)")
        rels = sorted(f"{rel}/{f.name}" for f in model.iterdir() if f.is_file())
        return SceneSource(name, path, folder, "colmap", "colmap", rel, files=_hashes(path, rels))
    if (path / "transforms_train.json").is_file():
        rels = [
            f"transforms_{s}.json"
            for s in ("train", "val", "test")
            if (path / f"transforms_{s}.json").is_file()
        ]
        return SceneSource(name, path, folder, "blender", "triangulated", files=_hashes(path, rels))
    raise StealthNSError(
        f"scene {name}: unknown dataset format in {folder}: no transforms.json (nerfstudio-data), "
        f"{' / '.join(COLMAP_DIRS)} with images/ (COLMAP) or transforms_train.json (Blender)"
    )


def seeded_dir(output: Path, name: str) -> Path:
    """``OUTPUT/scenes/NAME``: the seeded copy of a dataset folder without seed points."""
    return output / "scenes" / name


def seed_points_marker(output: Path, name: str) -> Path:
    return output / "scenes" / f"{name}{SEED_POINTS_MARKER}"


def read_seed_points(output: Path, source: SceneSource) -> dict[str, Any] | None:
    """The record of ``source``'s triangulated seed points when it is still valid: made from the
    same folder with the same content, and the dataset and point cloud it names exist."""
    try:
        data = json.loads(seed_points_marker(output, source.name).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or (data.get("source"), data.get("source_sha256")) != (
        str(source.path),
        source.sha256,
    ):
        return None
    try:
        if not (Path(data["dataset"]).exists() and Path(data["ply"]).is_file()):
            return None
    except (KeyError, TypeError):
        return None
    return data


def ensure_seed_points(output: Path, source: SceneSource) -> dict[str, Any]:
    """Triangulate the seed points of a dataset folder into ``OUTPUT/scenes/NAME`` unless a valid
    record of them is there (:func:`read_seed_points`); returns the record."""
    record = read_seed_points(output, source)
    if record is not None:
        return record
    try:
        from stealth_ns.seed_points import make_seed_points
    except ImportError as err:
        raise StealthNSError(
            f"cannot make seed points: stealth_ns.seed_points is not available ({err})"
        ) from None
    folder = seeded_dir(output, source.name)
    print(f"triangulating the seed points of {source.name} ({source.path}) into {folder}", flush=True)
    assert source.path is not None
    summary = make_seed_points(source.path, output=folder, overwrite=True, seed=0)
    ply = Path(summary.ply).absolute()
    record = {
        "source": str(source.path),
        "source_sha256": source.sha256,
        "format": source.format,
        "dataset": str(Path(summary.dataset).absolute()),
        "ply": str(ply),
        "ply_sha256": file_sha256(ply),
        "n_points": int(summary.n_points),
        "seconds": round(float(summary.seconds), 2),
        "seed": 0,
        "made_at": _dt.datetime.now().astimezone().isoformat(timespec="seconds"),
    }
    write_json_atomic(seed_points_marker(output, source.name), record)
    print(f"  {record['n_points']} seed points in {record['seconds']:.0f} s: {ply}", flush=True)
    return record


# ------------------------------------------------------------------------------ options
def parse_tables(values: Sequence[str | int] | None) -> tuple[int, ...]:
    """Table numbers from ``--tables`` values (``6``, ``"1,2"``, ``"all"``); None = all."""
    known = tuple(t.number for t in TABLES)
    if values is None:
        return known
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


def parse_scenes(values: Sequence[str] | None) -> tuple[tuple[SceneSource, ...], tuple[str, ...]]:
    """The scenes of ``--scenes`` (None: :data:`DEFAULT_SCENES`) and one "skipping ..." line per
    dataset folder of the default that is absent.

    Values are presets (``orbit``), ``all`` (the default list), a declared folder by its name
    (``fox``: its default path) or ``NAME=PATH`` (a dataset folder; the path may hold commas and
    spaces). A folder given explicitly must exist; one of the default list (or of ``all``) that
    does not is skipped. Bad specs raise :class:`StealthNSError`: unknown name, empty path, a
    name given twice, a folder named like a preset, a missing folder, an unknown dataset format.
    """
    optional_default = values is None
    specs: list[tuple[str, str | None, bool]] = []  # (name, folder or None for a preset, optional)
    for value in DEFAULT_SCENES if values is None else values:
        text = str(value).strip()
        for item in [text] if "=" in text else text.replace(",", " ").split():
            if item.lower() == "all":
                specs += [_scene_spec(v, optional=True) for v in DEFAULT_SCENES]
            else:
                specs.append(_scene_spec(item, optional=optional_default))
    if not specs:
        raise StealthNSError(f"no scene given; scenes: {_known_scenes()}")
    seen: dict[str, str | None] = {}
    chosen: list[tuple[str, str | None, bool]] = []
    for name, folder, optional in specs:
        if name in seen:
            if folder is None and seen[name] is None:
                continue  # a preset twice ("all orbit"): the same scene
            raise StealthNSError(f"scene {name!r} is given twice in --scenes")
        seen[name] = folder
        chosen.append((name, folder, optional))
    sources: list[SceneSource] = []
    skipped: list[str] = []
    for name, folder, optional in chosen:
        if folder is None:
            sources.append(SceneSource(name))
        elif optional and not Path(folder).expanduser().exists():
            skipped.append(
                f"skipping {name}: {folder} not found (a dataset folder of the default --scenes; "
                f"give --scenes {name}=PATH to use it from elsewhere)"
            )
        else:
            sources.append(inspect_folder(name, folder))
    order = {name: i for i, name in enumerate(SCENES)}
    sources.sort(key=lambda src: order.get(src.name, len(order)))  # stable: other folders as given
    return tuple(sources), tuple(skipped)


def _known_scenes() -> str:
    return f"{' '.join(SCENES)}, or NAME=PATH for a dataset folder"


def _scene_spec(item: str, optional: bool) -> tuple[str, str | None, bool]:
    """``(name, folder or None, optional)`` of one ``--scenes`` item."""
    if "=" not in item:
        if item in PRESETS:
            return item, None, False
        if item in FOLDERS:
            return item, FOLDERS[item], optional
        raise StealthNSError(f"unknown scene {item!r}; scenes: {_known_scenes()}")
    name, folder = (part.strip() for part in item.split("=", 1))
    if not _SCENE_NAME.fullmatch(name) or name.lower() == "all":
        raise StealthNSError(
            f"bad scene name {name!r} in {item!r}: use letters, digits, '_', '-' and '.' (NAME=PATH)"
        )
    if name in PRESETS or any(name.startswith(f"{p}-seed") for p in PRESETS):
        raise StealthNSError(
            f"scene name {name!r} ({item!r}) is taken by the generated preset {name.split('-')[0]}; "
            "give the folder another name"
        )
    if not folder:
        raise StealthNSError(f"no folder given for scene {name!r} ({item!r}); use NAME=PATH")
    return name, folder, optional


def method_config(method: str) -> Any:
    """The ``TrainerConfig`` a stealth-ns method is registered with (its nerfstudio entry point; shared:
    copy it before changing it)."""
    from importlib.metadata import entry_points

    if method not in METHODS:
        raise StealthNSError(f"unknown method {method!r}; methods: {', '.join(METHODS)}")
    for ep in entry_points(group="nerfstudio.method_configs"):
        if ep.name == method:
            return ep.load().config
    raise StealthNSError(f"method {method!r} is not registered with nerfstudio (is stealth-ns installed?)")


def method_iterations(method: str) -> int:
    """The default ``max_num_iterations`` of a stealth-ns method."""
    return int(method_config(method).max_num_iterations)


# ------------------------------------------------------------------------------ the plan
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


def scene_dir(output: Path, preset: str, seed: int, scene_options: dict[str, Any] | None = None) -> Path:
    """``OUTPUT/scenes/PRESET-seedS`` (with the resolution and view count when not the defaults)."""
    name = f"{preset}-seed{seed}"
    if scene_options:
        name += "".join(f"-{k}{v}" for k, v in sorted(scene_options.items()))
    return output / "scenes" / name


def _scene_info(path: Path) -> dict[str, Any] | None:
    try:
        info = json.loads((path / "scene.json").read_text())
    except (OSError, ValueError):
        return None
    return info if isinstance(info, dict) and (path / "transforms.json").is_file() else None


def scene_is_ready(path: Path, preset: str, seed: int, scene_options: dict[str, Any] | None = None) -> bool:
    """True when ``path`` holds a completely generated scene of this preset and seed.

    ``make_scene`` writes ``scene.json`` last, so its presence means the scene is complete.
    """
    info = _scene_info(path)
    if info is None or info.get("preset") != preset or info.get("seed") != seed:
        return False
    opts = scene_options or {}
    if "views" in opts and info.get("views") != opts["views"]:
        return False
    if "resolution" in opts:
        width, height = (int(v) for v in str(opts["resolution"]).lower().split("x"))
        if info.get("resolution") != [width, height]:
            return False
    return True


def ensure_scene(path: Path, preset: str, seed: int, scene_options: dict[str, Any] | None = None) -> None:
    """Generate the scene unless a complete one is there."""
    if scene_is_ready(path, preset, seed, scene_options):
        return
    from stealth_ns.scenes import make_scene

    print(f"generating the {preset} scene in {path}", flush=True)
    make_scene(preset=preset, output=path, seed=seed, overwrite=True, **(scene_options or {}))


def kde_views(dataset: Path, cache: Path, fingerprint: str, write_cache: bool) -> dict[str, str]:
    """Easy / Median / Hard training views of a dataset by the KDE protocol (``rank_scene_views``).

    Cached in ``cache`` (next to the scene, under ``OUTPUT/scenes``) while the dataset's
    ``fingerprint`` (a generated scene's scene.json, a folder's content hash) is the same.
    """
    try:
        data = json.loads(cache.read_text())
        if data.get("fingerprint") == fingerprint and set(data.get("views", {})) == set(KDE_LEVELS):
            return {k: str(v) for k, v in data["views"].items()}
    except (OSError, ValueError, AttributeError):
        pass
    try:
        from stealth_ns.evaluation.difficulty import rank_scene_views
    except ImportError as err:
        raise StealthNSError(f"the KDE difficulty protocol is not available ({err})") from None
    ranking = rank_scene_views(dataset)
    views = {"easy": ranking.easy, "median": ranking.median, "hard": ranking.hard}
    if write_cache:
        cache.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(cache, {"fingerprint": fingerprint, "dataset": str(dataset), "views": views})
    return views


def _scene_fingerprint(plan_dir: Path, src: SceneSource, record: dict[str, Any] | None) -> str:
    if src.is_preset:
        return (plan_dir / "scene.json").read_text()
    return src.sha256 + (f":{record['ply_sha256']}" if record else "")


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
) -> Plan:
    """Plan the runs of ``tables`` on ``scenes`` (bad input: :class:`StealthNSError`).

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
            fingerprint = _scene_fingerprint(dirs[scene], src, records.get(scene))
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
    )


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
        table = get_table(number).for_scenes(scenes).for_attacks(attacks)
        keys = table.run_keys(scenes)
        if not keys:
            skipped.append(f"Table {number} skipped: it runs on {', '.join(table.scenes)}, not in --scenes")
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
    """The ns-train invocation of ``run`` (shown in ``tables``): its scene's options, the KDE view
    (a placeholder until ranked), the attack seed, the run folder; with its status on disk."""
    src = src_of[run.scene]
    extra = [*src.train_args, *run.args]
    view = None
    if run.view in KDE_LEVELS:
        view = views.get(run.scene, {}).get(run.view) or f"<{run.view.upper()} view of the KDE protocol>"
        if not run.poisoning:
            extra += ["--pipeline.attack.views", view]
    if not run.clean and not run.poisoning:
        extra += ["--pipeline.attack.seed", str(seed)]
    dataparser, dataparser_args = src.dataparser
    # a preset's folder name holds its seed and options; a folder's experiment names the training seed
    experiment = dirs[run.scene].name if src.is_preset else f"{run.scene}-seed{seed}"
    data, scene_id = dirs[run.scene], None if src.is_preset else f"{run.scene}:{src.sha256[:16]}"
    poison = None
    if run.poisoning:  # a plain victim on the poisoned copy of the scene
        folder = output / "poisoned" / f"{experiment}-{iterations}it" / run.name
        poison = PoisonJob(
            run.poisoning, dirs[run.scene], folder, view, run.poison_args, method, seed, iterations, scene_id
        )
        data, scene_id = folder, poison.scene_id
    spec = TrainSpec(
        scene=data,
        name=run.name,
        output_dir=output / "runs",
        experiment=f"{experiment}-{iterations}it",
        extra=tuple(extra),
        method=method,
        iterations=int(iterations),
        seed=int(seed),
        dataparser=dataparser,
        dataparser_args=dataparser_args,
        scene_id=scene_id,
    )
    return PlannedRun(run, spec, run_status(spec), tuple(sorted(set(tables))), view, poison)


# ------------------------------------------------------------------------------ running it
def cached_pair_metrics(
    poisoned: PlannedRun, poisoned_rec: TrainRecord, clean: PlannedRun, clean_rec: TrainRecord
) -> tuple[dict[str, Any], float, bool]:
    """``compare_runs`` of a poisoned run and its clean baseline, cached in ``metrics.json``.

    Returns ``(metrics, seconds, cached)``; the cache holds while neither run is retrained.
    """
    cache = poisoned.spec.run_dir / METRICS_FILE
    stamp = {"poisoned_run_id": poisoned_rec.run_id, "clean_run_id": clean_rec.run_id}
    try:
        data = json.loads(cache.read_text())
        if data.get("stamp") == stamp and isinstance(data.get("metrics"), dict):
            return data["metrics"], float(data.get("seconds", 0.0)), True
    except (OSError, ValueError, AttributeError):
        pass
    from stealth_ns.evaluation import report

    t0 = time.perf_counter()
    # loading two runs in-process is chatty (nerfstudio's console, warnings): keep it in a log
    with (poisoned.spec.run_dir / METRICS_LOG).open("w") as log, redirect_stdout(log), redirect_stderr(log):
        try:
            metrics = json_safe(report.compare_runs(poisoned.spec.config_path, clean.spec.config_path))
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


def _git_commit() -> str | None:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=Path(__file__).resolve().parent,
            capture_output=True,
            text=True,
            timeout=10,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    commit = out.stdout.strip()
    return commit if out.returncode == 0 and commit else None


def environment(plan: Plan, started: float, executor: dict[str, Any] | None = None) -> dict[str, Any]:
    """Method, iterations, seed, date, versions and hardware of this benchmark, and where it trained
    (``executor``: the executor's record; default: the plan's options)."""
    return {
        "method": plan.method,
        "iterations": plan.iterations,
        "seed": plan.seed,
        "scene_seed": plan.seed,
        "attack_noise_seed": plan.seed,
        "date": _dt.datetime.now().astimezone().isoformat(timespec="seconds"),
        "wall_seconds": round(time.time() - started, 1),
        **software_and_hardware(),
        "git_commit": _git_commit(),
        "executor": executor or {"name": plan.executor.name},
    }


def _run_entry(p: PlannedRun) -> dict[str, Any]:
    return {
        "scene": p.run.scene,
        "name": p.run.name,
        "label": p.run.label,
        "clean": p.run.clean,
        "tables": list(p.tables),
        "view_choice": p.run.view,
        "kde_view": p.view,
        "args": list(p.spec.extra),
        "run_dir": str(p.spec.run_dir),
        "config": str(p.spec.config_path),
        "command": p.spec.command(),
        "status": "pending",
    }


def _folder_info(src: SceneSource) -> dict[str, Any]:
    """Views and resolution of a nerfstudio-data folder (from its transforms.json), else unknowns."""
    info: dict[str, Any] = {"resolution": None, "views": None}
    if src.format != "nerfstudio-data" or src.path is None:
        return info
    try:
        meta = json.loads((src.path / "transforms.json").read_text(encoding="utf-8"))
        frames = meta["frames"]
        first = frames[0] if frames else {}
        w, h = first.get("w", meta.get("w")), first.get("h", meta.get("h"))
        info["views"] = len(frames)
        info["resolution"] = [int(w), int(h)] if w and h else None
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        pass
    return info


def scene_entry(plan: Plan, scene: str) -> dict[str, Any]:
    """A scene's record in results.json: where it comes from (preset + seed, or folder + content
    hash), what it trains on, its seed points and KDE views."""
    src = plan.sources.get(scene, SceneSource(scene))
    dataparser, dataparser_args = src.dataparser
    entry: dict[str, Any] = {
        "kind": scene_kind(scene),
        "dataset": str(plan.scene_dirs[scene]),
        "dataparser": [dataparser, *dataparser_args],
    }
    if src.is_preset:
        info = _scene_info(plan.scene_dirs[scene]) or {}
        entry.update(
            source="preset",
            preset=scene,
            seed=plan.seed,
            path=str(plan.scene_dirs[scene]),
            resolution=info.get("resolution"),
            views=info.get("views"),
            n_train=info.get("n_train"),
            n_test=info.get("n_test"),
            seed_points="generated",
        )
    else:
        entry.update(
            source="folder",
            path=str(src.path),
            given=src.given,
            format=src.format,
            content_sha256=src.sha256,
            files_sha256=dict(src.files),
            **_folder_info(src),
            seed_points=src.seed_points,
        )
        if src.triangulated:
            entry["seed_points_made"] = plan.seed_points.get(scene)
    entry["kde_views"] = plan.views.get(scene)
    if scene in plan.scene_errors:
        entry["error"] = plan.scene_errors[scene]
    return entry


def build_results(plan: Plan, runs: dict[str, dict[str, Any]], env: dict[str, Any], complete: bool) -> dict:
    """The results.json document: environment, scenes, runs (with metrics) and the tables' numbers."""
    return {
        "generator": "stealth-ns bench attack",
        "complete": complete,
        "environment": env,
        "not_implemented": NOT_IMPLEMENTED,
        "success_rule": SUCCESS_RULE,
        "scenes": {scene: scene_entry(plan, scene) for scene in plan.scenes},
        "skipped_scenes": list(plan.skipped_scenes),
        "runs": runs,
        "tables": {str(t.number): table_data(t, runs, plan.scenes) for t in plan.tables},
    }


def _write_outputs(
    plan: Plan,
    runs: dict[str, dict[str, Any]],
    started: float,
    complete: bool,
    executor: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Write results.json and tables.md (each replaced whole); returns the results document."""
    results = json_safe(build_results(plan, runs, environment(plan, started, executor), complete))
    write_results(plan.output, results)
    return results


def write_results(output: Path, results: dict[str, Any]) -> None:
    """``output/results.json`` and ``output/tables.md`` of ``results``, each replaced whole."""
    output.mkdir(parents=True, exist_ok=True)
    write_json_atomic(output / "results.json", results)
    tmp = output / ".tables.md.tmp"
    tmp.write_text(render_markdown(results))
    tmp.replace(output / "tables.md")


class _Bench:
    """The bookkeeping of one :func:`execute`: results entries, finished records, the bar and the log
    lines; it hears the executor's events and outcomes (:mod:`stealth_ns.evaluation.executors`).

    A poisoned run's metrics need its scene's clean run: with the local executor the clean run
    always comes first (the plan's order); with Ray a poisoned run that finishes first waits, and
    its metrics follow the clean run's line.
    """

    def __init__(self, plan: Plan, executor: Executor, bar: Any, started: float) -> None:
        self.plan, self.executor, self.bar, self.t0 = plan, executor, bar, started
        self.runs = {p.key: _run_entry(p) for p in plan.runs}
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
        return _write_outputs(self.plan, self.runs, self.t0, complete, self.executor.record())

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
    note = f"; V-illusory {_fmt(ill, 2)} dB, V-test drop {_fmt(drop, 2)} dB"
    return note + (", attack succeeds" if metrics.get("attack_success") else ", attack fails")


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
) -> Plan | dict[str, Any]:
    """``stealth-ns bench attack``: the plan (``dry_run``) or the results document.

    ``executor``: where the trainings run (``--executor`` and its options; default local).
    ``defend``: also Table D (:mod:`stealth_ns.evaluation.defence_table`), which needs Table 1's runs.
    """
    options = (executor or ExecutorOptions()).checked()
    if defend:
        tables = (*parse_tables(tables), 1)
    # without --dry-run this first plan only checks the input: the views are ranked below
    plan = bench_plan(
        output, tables, scenes, method, iterations, seed, scene_options, rank_views=dry_run, attacks=attacks
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
    from stealth_ns.evaluation.defence_table import defend_scenes

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


# ------------------------------------------------------------------------------ the tables
METRIC_NAMES = (("psnr", "PSNR↑", 2), ("ssim", "SSIM↑", 3), ("lpips", "LPIPS↓", 3))
FAMILY_LABELS = {"v_illusory": "V-illusory", "v_test": "V-test"}
MISSING = "n/a"


def _metric_key(family: str, metric: str, naive: bool) -> str:
    if family == "v_illusory":
        return f"v_illusory_clean_{metric}" if naive else f"v_illusory_{metric}"
    return f"v_test_{metric}_clean" if naive else f"v_test_{metric}"


def table_data(table: TableSpec, runs: dict[str, dict[str, Any]], scenes: Sequence[str]) -> dict[str, Any]:
    """A table's header and numbers from the runs' metrics (``"n/a"`` where a run has none).

    Only the column groups of ``scenes`` are kept. Values are floats, None (a metric the run
    could not compute, e.g. LPIPS without its weights) or ``"n/a"`` (run failed or missing).
    """
    groups = [(i, g) for i, g in enumerate(table.groups) if g.scene in scenes]
    multi_group = len(table.groups) > 1  # label the scene even when --scenes keeps one group
    columns: list[dict[str, Any]] = []
    for _, g in groups:
        for family in g.metrics:
            for metric, label, digits in METRIC_NAMES:
                parts = [g.label if multi_group else "", FAMILY_LABELS[family], label]
                columns.append({"label": " ".join(p for p in parts if p), "metric": metric, "digits": digits})
    rows = []
    lpips_notes: set[str] = set()
    missing_runs: set[str] = set()
    for row in table.rows:
        values: list[Any] = []
        successes: list[bool] = []
        for i, g in groups:
            key = f"{g.scene}/{row.runs[i]}"
            metrics = (runs.get(key) or {}).get("metrics")
            if not isinstance(metrics, dict):
                missing_runs.add(key)
            elif metrics.get("lpips_unavailable"):
                lpips_notes.add(str(metrics["lpips_unavailable"]))
            if isinstance(metrics, dict) and not row.naive:
                successes.append(bool(metrics.get("attack_success")))
            for family in g.metrics:
                for metric, _, _ in METRIC_NAMES:
                    if not isinstance(metrics, dict):
                        values.append(MISSING)
                    else:
                        v = metrics.get(_metric_key(family, metric, row.naive))
                        values.append(float(v) if isinstance(v, (int, float)) else None)
        entry: dict[str, Any] = {
            "keys": list(row.keys),
            "runs": [f"{g.scene}/{row.runs[i]}" for i, g in groups],
            "naive": row.naive,
            "values": values,
        }
        if table.asr:
            entry["asr"] = f"{sum(successes)}/{len(successes)}" if successes else MISSING
        rows.append(entry)
    return {
        "number": table.number,
        "title": table.title,
        "key_header": list(table.key_header),
        "columns": columns,
        "asr": table.asr,
        "rows": rows,
        "notes": list(table.notes),
        "lpips_unavailable": sorted(lpips_notes),
        "missing_runs": sorted(missing_runs),
    }


def _fmt(value: Any, digits: int) -> str:
    if value == MISSING:
        return MISSING
    if value is None:
        return "–"
    text = f"{float(value):.{digits}f}"
    return text[1:] if text.startswith("-") and float(text) == 0 else text  # no "-0.00"


def render_table(data: dict[str, Any]) -> str:
    """One table of :func:`table_data` as markdown; the best attack value of each column in bold."""
    columns = data["columns"]
    header = [*data["key_header"], *(c["label"] for c in columns)]
    if data["asr"]:
        header.append(f"ASR ({SUCCESS_RULE})")
    best: list[str | None] = []
    for j, col in enumerate(columns):
        vals = [r["values"][j] for r in data["rows"] if not r["naive"] and isinstance(r["values"][j], float)]
        texts = {_fmt(v, col["digits"]) for v in vals}
        if len(texts) < 2:  # one row, or all equal: nothing to single out
            best.append(None)
            continue
        pick = min(vals) if col["metric"] == "lpips" else max(vals)
        best.append(_fmt(pick, col["digits"]))
    lines = [f"## Table {data['number']}: {data['title']}", ""]
    lines.append("| " + " | ".join(header) + " |")
    lines.append(
        "|"
        + "|".join([":--"] * len(data["key_header"]) + ["--:"] * (len(header) - len(data["key_header"])))
        + "|"
    )
    for r in data["rows"]:
        cells = list(r["keys"])
        for j, col in enumerate(columns):
            text = _fmt(r["values"][j], col["digits"])
            cells.append(
                f"**{text}**" if not r["naive"] and best[j] is not None and text == best[j] else text
            )
        if data["asr"]:
            cells.append(r["asr"])
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    notes = list(data["notes"])
    for reason in data["lpips_unavailable"]:
        notes.append(f"LPIPS shown as –: {reason}")
    if data["missing_runs"]:
        notes.append(
            f"{MISSING}: no numbers for {', '.join(data['missing_runs'])} (run failed, interrupted or not "
            "run yet; see results.json and the run's ns-train.log)"
        )
    lines += [f"- {note}" for note in notes]
    return "\n".join(lines) + "\n"


def _runs_table(runs: dict[str, dict[str, Any]]) -> str:
    header = [
        "Run", "Settings", "Poisoned view(s)", "V-illusory PSNR", "V-test PSNR (clean → poisoned)",
        "Drop", "Success", "Gaussians (poison)", "Training", "This invocation",
    ]  # fmt: skip
    lines = ["## All runs", "", "| " + " | ".join(header) + " |", "|" + "|".join([":--"] * len(header)) + "|"]
    for key, e in runs.items():
        m = e.get("metrics") if isinstance(e.get("metrics"), dict) else None
        seconds = e.get("train_seconds")
        train_time = f"{seconds / 60:.1f} min" if isinstance(seconds, (int, float)) else MISSING
        if m is not None:
            views = ", ".join(m.get("poisoned_views") or [])
            test = f"{_fmt(m.get('v_test_psnr_clean'), 2)} → {_fmt(m.get('v_test_psnr'), 2)}"
            gauss = f"{m.get('n_gaussians', MISSING)} ({m.get('n_poison_gaussians', MISSING)})"
            cells = [
                views, _fmt(m.get("v_illusory_psnr"), 2), test, _fmt(m.get("v_test_drop"), 2),
                "yes" if m.get("attack_success") else "no", gauss,
            ]  # fmt: skip
        elif e.get("clean"):
            cells = ["–", "–", "–", "–", "–", "–"]
        else:
            cells = [e.get("kde_view") or MISSING, MISSING, MISSING, MISSING, MISSING, MISSING]
        status = e.get("status", MISSING)
        if e.get("metrics_error"):
            status += " (metrics failed)"
        lines.append("| " + " | ".join([key, e.get("label", ""), *cells, train_time, status]) + " |")
    return "\n".join(lines) + "\n"


def _scene_text(name: str, scene: dict[str, Any]) -> str:
    size = "x".join(map(str, scene["resolution"])) if scene.get("resolution") else "?"
    where = "" if scene.get("source", "preset") == "preset" else f"folder {scene.get('path')}, "
    return f"{name} ({where}{size}, {scene.get('views') or '?'} views)"


def _executor_text(executor: Any) -> str:
    """A sentence for tables.md when the runs trained as Ray tasks (nothing for local runs)."""
    if not isinstance(executor, dict) or executor.get("name") != "ray":
        return ""
    amounts = {k: executor.get(f"{k.lower()}s_per_run") for k in ("CPU", "GPU")}
    per_run = [f"{v:g} {k}" for k, v in amounts.items() if isinstance(v, (int, float))]
    return (
        f" Trained as Ray tasks on a cluster of {executor.get('nodes', '?')} node(s) "
        f"({', '.join(per_run) or '?'} per run); the device above is the driver's, each run's node is "
        "in results.json."
    )


def render_markdown(results: dict[str, Any]) -> str:
    """``tables.md``: a header (method, environment, what is not implemented), the tables, all runs."""
    env = results.get("environment", {})
    scenes = results.get("scenes", {})
    scene_text = ", ".join(_scene_text(name, s) for name, s in scenes.items())
    lines = [
        "# StealthAttack experiments: the paper's tables on generated scenes and dataset folders",
        "",
        f"Produced by `stealth-ns bench attack` on {env.get('date', '?')}: method "
        f"{env.get('method', '?')}, {env.get('iterations', '?')} iterations, seed {env.get('seed', '?')}, "
        f"device {env.get('device', '?')} ({env.get('cpu_count', '?')} CPU cores); torch "
        f"{env.get('torch', '?')}, nerfstudio {env.get('nerfstudio', '?')}, "
        f"gsplat {env.get('gsplat') or '–'}, numpy {env.get('numpy', '?')}. Scenes: {scene_text or '?'}."
        + _executor_text(env.get("executor")),
        "",
        "Every number is measured from the runs listed at the end; `results.json` next to this file has "
        "all of them, with timings. V-illusory: masked metrics of the poisoned view(s) against the "
        "illusion target; V-test: held-out views against the clean images. Attack success: "
        f"{SUCCESS_RULE} against the clean run of the same scene.",
        "",
        results.get("not_implemented", NOT_IMPLEMENTED),
        "",
    ]
    if not results.get("complete", True):
        lines += ["**Incomplete**: some runs have not finished (or failed); their cells read n/a.", ""]
    for number in sorted(results.get("tables", {}), key=int):
        lines.append(render_table(results["tables"][number]))
    if results.get("table_d"):
        from stealth_ns.evaluation.defence_table import render_table as render_defence_table

        lines.append(render_defence_table(results["table_d"]))
    lines.append(_runs_table(results.get("runs", {})))
    return "\n".join(lines)
