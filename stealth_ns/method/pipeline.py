"""``StealthPipeline``: nerfstudio's VanillaPipeline with the attack built in.

At construction it resolves the attack (poisoned views, illusion placement, targets) and
fails with a one-line error on bad input before any training starts. When training starts
(``get_training_callbacks``) it hands the datamanager the poisoned targets and the noise
schedule, writes the attack's artifacts, and registers the density-guided injection.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.engine.callbacks import TrainingCallback, TrainingCallbackAttributes, TrainingCallbackLocation
from nerfstudio.pipelines.base_pipeline import VanillaPipeline, VanillaPipelineConfig
from nerfstudio.utils.rich_utils import CONSOLE

from stealth_ns.attack.config import AttackConfig
from stealth_ns.attack.illusion import (
    BUILTIN_ILLUSIONS,
    Illusion,
    builtin_illusion,
    composite,
    load_illusion,
    place_illusion,
)
from stealth_ns.attack.injection import CAMERA_PLACEMENTS, PoisonPlacement, injection_entry, place_poison
from stealth_ns.attack.record import (
    INJECTION_FILES,
    AttackRecord,
    PoisonView,
    write_injection_files,
)
from stealth_ns.attack.support import render_poison, support_target
from stealth_ns.attack.validation import validate_attack_config
from stealth_ns.attack.views import median_view, multi_view_indices, nearest_views, resolve_views
from stealth_ns.attack.visibility import CameraDepths
from stealth_ns.datasets.background import uniform_background
from stealth_ns.foundation import thread_invariant
from stealth_ns.foundation.errors import StealthNSError, fail
from stealth_ns.foundation.fingerprint import dataset_fingerprint, record_fingerprint
from stealth_ns.foundation.json_io import json_safe
from stealth_ns.images.io import to_float32, to_uint8
from stealth_ns.images.metrics import illusion_metrics, psnr, v_illusory
from stealth_ns.method.checkpoints import checkpoint_mismatch
from stealth_ns.method.datamanager import NoiseSpec, StealthDataManager, dataset_image_names
from stealth_ns.method.model import NEAR_PLANE, StealthSplatModel
from stealth_ns.method.viewer import StealthAttackPanel
from stealth_ns.raster.projection import viewmat_from_c2w


@dataclass
class StealthPipelineConfig(VanillaPipelineConfig):
    """Datamanager, model, and the attack (``--pipeline.attack.*``)."""

    _target: type = field(default_factory=lambda: StealthPipeline)
    attack: AttackConfig = field(default_factory=AttackConfig)
    """StealthAttack settings."""


def resolve_illusion(cfg: AttackConfig) -> Illusion:
    """The configured illusion: a built-in name or an image path (+ optional mask)."""
    if cfg.illusion in BUILTIN_ILLUSIONS:
        return builtin_illusion(cfg.illusion)
    path = Path(cfg.illusion)
    if not path.suffix and not path.exists():
        builtins = ", ".join(BUILTIN_ILLUSIONS)
        raise StealthNSError(
            f"unknown illusion {cfg.illusion!r}: use a built-in ({builtins}) or an image path"
        )
    return load_illusion(path, cfg.illusion_mask)


def build_poison_views(cfg: AttackConfig, datamanager: StealthDataManager) -> list[PoisonView]:
    """Resolve the poisoned views and their illusion targets; StealthNSError on bad input."""
    names = datamanager.train_image_names
    if cfg.multi_view not in (1, 2, 3, 4):
        raise StealthNSError(f"--pipeline.attack.multi-view must be 1..4, got {cfg.multi_view}")
    base = resolve_views(list(cfg.views), names) if cfg.views else [median_view(len(names))]
    cameras = datamanager.train_dataset.cameras
    if cfg.multi_view > 1:
        if len(base) != 1:
            raise StealthNSError(
                "--pipeline.attack.multi-view places views around ONE base view; give one view"
            )
        base = multi_view_indices(cameras.camera_to_worlds, cfg.multi_view, base=base[0])
    illusion = resolve_illusion(cfg)
    views = []
    for index in base:
        image = datamanager.cached_train[index]["image"]
        height, width = image.shape[:2]
        rgb, alpha = place_illusion(illusion, (height, width), cfg.illusion_center, cfg.illusion_scale)
        target = composite(rgb_float(image), torch.as_tensor(rgb), torch.as_tensor(alpha))
        cam = cameras[index]
        views.append(
            PoisonView(
                index=index,
                name=names[index],
                c2w=cam.camera_to_worlds.float(),
                fx=float(cam.fx),
                fy=float(cam.fy),
                cx=float(cam.cx),
                cy=float(cam.cy),
                mask=torch.as_tensor(alpha) > 0.5,
                target=target,
            )
        )
    return views


def check_seed_points(model: StealthSplatModel, datamanager: StealthDataManager) -> None:
    """Stop unless the model starts from seed points: the density-guided placement reads the
    density of the point cloud, and that of a random initialisation is noise."""
    points = model.seed_points[0] if model.seed_points is not None else None
    if model.config.random_init:
        why = "--pipeline.model.random-init is on"
    elif points is None and (named := _named_seed_point_file(datamanager)) is not None:
        why = named
    elif points is None:
        why = (
            "the dataset has no seed points (no ply_file_path in transforms.json, no COLMAP points, "
            "or a Blender dataset)"
        )
    elif points.shape[0] == 0:
        why = "the seed-point file is empty"
    else:
        return
    data = datamanager.config.dataparser.data
    fail(
        f"the density-guided injection places poison by the density of the seed points, but {why}. "
        f"Triangulate them from the known poses with `stealth-ns seed-points --data {data}` and train "
        "on the dataset it prints, or turn the component off with --pipeline.attack.density-guided False"
    )


def _named_seed_point_file(datamanager: StealthDataManager) -> str | None:
    """Why the seed-point file named by a nerfstudio-data transforms file gave no points, if it names one."""
    from stealth_ns.datasets.check import ply_vertex_count, read_json_object, transforms_path

    data = getattr(datamanager.config.dataparser, "data", None)
    if data is None:
        return None
    path = transforms_path(Path(data))
    try:
        ply = read_json_object(path).get("ply_file_path")
    except StealthNSError:  # not nerfstudio-data (colmap, blender): no named file
        return None
    if not isinstance(ply, str):
        return None
    ply_path = path.parent / ply  # its existence is checked at start-up (dataset_check)
    try:
        n = ply_vertex_count(ply_path)
    except StealthNSError as err:
        return str(err)
    return f"the seed-point file {ply_path} has no points" if n == 0 else None


def rgb_float(image: torch.Tensor) -> torch.Tensor:
    """[H, W, 3 or 4] uint8 or float cached image -> [H, W, 3] float32 in [0, 1], on the CPU."""
    return torch.from_numpy(to_float32(image[..., :3]))


def cached_format(rgb: torch.Tensor, clean: torch.Tensor, opaque: torch.Tensor | None = None) -> torch.Tensor:
    """A float [H, W, 3] training image in the cache's dtype/channels of ``clean``: images with alpha
    (blender) keep their alpha, made opaque where ``opaque`` ([H, W] bool) is set."""
    if clean.dtype == torch.uint8:
        rgb = (rgb * 255.0).round().clamp(0, 255).to(torch.uint8)
    if clean.shape[-1] == 4:
        a = clean[..., 3:].clone()
        if opaque is not None:
            a[opaque] = 255 if clean.dtype == torch.uint8 else 1.0
        rgb = torch.cat([rgb, a], -1)
    return rgb


def training_target(view: PoisonView, clean: torch.Tensor) -> torch.Tensor:
    """The poisoned view's training image in the cache's dtype/channels (RGBA keeps its alpha, and the
    illusion is opaque where its mask is)."""
    return cached_format(view.target, clean, view.mask)


class StealthPipeline(VanillaPipeline):
    """VanillaPipeline + StealthAttack (see the module docstring)."""

    config: StealthPipelineConfig
    model: StealthSplatModel
    datamanager: StealthDataManager

    def __init__(self, config: StealthPipelineConfig, device: str, *args: Any, **kwargs: Any) -> None:
        if kwargs.get("test_mode", args[0] if args else "val") != "inference":
            try:  # every attack option, before any data is loaded
                validate_attack_config(config.attack)
            except StealthNSError as err:
                fail(err)
        super().__init__(config, device, *args, **kwargs)
        if isinstance(self.model, StealthSplatModel):
            # chosen (and the compiled kernels built, ~30 s after an update) now, not in the first step:
            # the build used to be timed as the injection's
            _ = self.model.rasterizer_backend
        self.poison_views: list[PoisonView] = []
        self.support_views: dict[int, list[int]] = {}  # poisoned view -> its support views (train indices)
        self.attack_dir: Path | None = None
        self.record: AttackRecord | None = None  # set when training starts (or resumes)
        self._restored_record: dict[str, Any] | None = None  # attack.json content, from a loaded checkpoint
        self._loaded_step = -1
        self._saved_state: dict[str, Any] = {}  # the extra state of a loaded checkpoint
        self.stealth_attack = StealthAttackPanel(self)  # the viewer's panel; inert without a viewer
        cfg = config.attack
        if self.test_mode == "inference":  # ns-viewer / ns-export: no training data needed
            from stealth_ns.method.export import install_export_hook

            install_export_hook(self.model)
            return
        if not cfg.enabled:
            return
        if not isinstance(self.datamanager, StealthDataManager) or not isinstance(
            self.model, StealthSplatModel
        ):
            fail("the attack needs stealth-ns' datamanager and model (use the stealth-splat methods)")
        if cfg.density_guided:
            check_seed_points(self.model, self.datamanager)
        try:
            self.poison_views = build_poison_views(cfg, self.datamanager)
        except StealthNSError as err:
            fail(err)
        if not any(bool(v.mask.any()) for v in self.poison_views):
            fail("the illusion mask is empty in every poisoned view")
        poisoned = [v.index for v in self.poison_views]
        c2w = self.datamanager.train_dataset.cameras.camera_to_worlds
        try:
            k = cfg.support_views
            self.support_views = {i: nearest_views(c2w, i, k, exclude=poisoned) for i in poisoned if k}
        except StealthNSError as err:
            fail(err)

    # ------------------------------------------------------------------ training set-up
    @property
    def injection_step(self) -> int:
        step = self.config.attack.injection_step
        return self.model.config.warmup_length if step is None else step

    def get_training_callbacks(self, attrs: TrainingCallbackAttributes) -> list[TrainingCallback]:
        try:
            callbacks = super().get_training_callbacks(attrs)
        except StealthNSError as err:
            fail(err)
        if attrs.trainer is not None:  # clean or attacked: which dataset (stealth-ns report checks it)
            record_fingerprint(
                Path(attrs.trainer.base_dir), self.train_fingerprint, self.datamanager.config.dataparser.data
            )
            self._say_background()
        if not self.config.attack.enabled or not self.poison_views:
            return callbacks
        restored = self._restored_record
        noise = self._start_poisoning(attrs, restored)
        if attrs.trainer is not None:
            self.attack_dir = Path(attrs.trainer.base_dir) / "attack"
        if restored is not None:
            self._continue_record(restored, attrs)
        else:
            self.record = AttackRecord(
                config=dataclasses.asdict(self.config.attack),
                views=self.poison_views,
                injection_step=self.injection_step if self.config.attack.density_guided else None,
                noise=None if noise is None else dataclasses.asdict(noise),
            )
            self._write_record(views=True)
        return callbacks + self._injection_callbacks()

    def _say_background(self) -> None:
        """Say so when RGB training images sit on a uniform white or black background and the model
        trains under a random one (:mod:`stealth_ns.datasets.background`)."""
        if self.model.config.background_color != "random":
            return
        n = len(self.datamanager.train_dataset)
        picks = sorted({int(i) for i in np.linspace(0, n - 1, min(n, 8)).round()})
        cached = self.datamanager.cached_train
        found = uniform_background(to_uint8(cached[i]["image"].cpu().numpy()) for i in picks)
        if found is not None:
            colour, share = found
            CONSOLE.print(
                f"stealth-ns: warning: the training images sit on a uniform {colour} background "
                f"({share:.0%} of {len(picks)} looked at): under the random background the model must "
                f"paint it with Gaussians; train with --pipeline.model.background-color {colour}",
                soft_wrap=True,
            )

    def _start_poisoning(
        self, attrs: TrainingCallbackAttributes, restored: dict[str, Any] | None
    ) -> NoiseSpec | None:
        """Hand the datamanager the poisoned targets and the noise schedule (a resumed run: the original
        one); stop with a one-line error when the injection step lies past the run's end."""
        cfg = self.config.attack
        max_steps = attrs.trainer.config.max_num_iterations if attrs.trainer is not None else 30_000
        if restored is not None and restored.get("noise"):
            max_steps = int(restored["noise"]["total_steps"])
        if restored is None and cfg.density_guided and self.injection_step >= max_steps:  # injects nothing
            given = "" if cfg.injection_step is not None else " (None: the end of the model's warm-up)"
            fail(
                f"--pipeline.attack.injection-step must be None or a step in [0, {max_steps}) "
                f"(the run's --max-num-iterations), got {self.injection_step}{given}: "
                "no poison Gaussian would be injected"
            )
        if restored is not None and cfg.support_views:
            fail(
                "resuming a run of --pipeline.attack.support-views is not supported (its support views' "
                "images are rendered at the injection): train it again"
            )
        targets = {}
        if cfg.gt_replacement:
            for v in self.poison_views:
                targets[v.index] = training_target(v, self.datamanager.cached_train[v.index]["image"])
        noise = NoiseSpec(cfg.noise_sigma0, cfg.noise_decay, max_steps, cfg.seed) if cfg.view_noise else None
        self.datamanager.set_poison(targets, noise)
        return noise

    def _injection_callbacks(self) -> list[TrainingCallback]:
        """The injection, unless the record says it happened (a resumed run)."""
        if not self.config.attack.density_guided or (self.record is not None and self.record.injection):
            return []
        return [
            TrainingCallback(
                where_to_run=[TrainingCallbackLocation.BEFORE_TRAIN_ITERATION],
                func=self.inject_poison,
                iters=(self.injection_step,),
            )
        ]

    # ------------------------------------------------------------------ checkpoints and resuming
    def get_extra_state(self) -> dict[str, str]:
        """Stored in every checkpoint: the attack record, which a resumed run continues, and the
        training images' fingerprint, by which a loaded checkpoint is matched to its dataset."""
        state = {"attack_record": "{}" if self.record is None else self.record.dumps()}
        if self.test_mode != "inference":
            state["train_images"] = json.dumps(self.train_images_fingerprint)
        return state

    def set_extra_state(self, state: Any) -> None:
        self._saved_state = dict(state) if isinstance(state, dict) else {}
        if self._saved_state.get("attack_record"):
            self._restored_record = json.loads(self._saved_state["attack_record"]) or None

    @functools.cached_property
    def train_fingerprint(self) -> dict[str, Any]:
        """The training split's :func:`~stealth_ns.foundation.fingerprint.dataset_fingerprint` (its images
        hashed once: ``dataset.json`` and every checkpoint use it)."""
        return dataset_fingerprint(self.datamanager.train_dataparser_outputs)

    @property
    def train_images_fingerprint(self) -> dict[str, Any]:
        """The part of :attr:`train_fingerprint` a checkpoint keeps: image count and content hash (the
        poses are left out: nerfstudio changes undistorted cameras in place)."""
        return {k: self.train_fingerprint[k] for k in ("version", "n_images", "images")}

    def load_pipeline(self, loaded_state: dict[str, Any], step: int) -> None:
        """Load a checkpoint (resuming, or a run loaded for evaluation), refusing one of another
        dataset or another attack (:func:`stealth_ns.method.checkpoints.checkpoint_mismatch`)."""
        state = dict(loaded_state)
        state.setdefault("_extra_state", {})  # checkpoint from before the record was stored
        self._loaded_step = step
        super().load_pipeline(state, step)
        if self.test_mode == "inference":
            return
        attack = json_safe(dataclasses.asdict(self.config.attack)) if self.config.attack.enabled else None
        resuming = self.test_mode == "val"  # ns-train; a run loaded for evaluation is in "test"
        why = checkpoint_mismatch(self._saved_state, attack, self.train_images_fingerprint, resuming)
        if why is not None:
            data = self.datamanager.config.dataparser.data
            fail(f"the checkpoint of step {step} does not belong to the run on {data}: {why}")

    def _continue_record(self, restored: dict[str, Any], attrs: TrainingCallbackAttributes) -> None:
        """A run resumed from a checkpoint (``--load-dir``): carry its record on, say where it
        resumed and with how many poison Gaussians, and copy its injection artifacts over."""
        self.record = AttackRecord.from_json(restored, self.poison_views)
        resumed = {"step": self._loaded_step + 1, "poison_gaussians": int(self.model.poison_mask.sum())}
        load_dir = getattr(getattr(attrs.trainer, "config", None), "load_dir", None)
        if load_dir is not None:
            resumed["from"] = str(Path(load_dir).parent)
            previous = Path(load_dir).parent / "attack"
            if self.attack_dir is not None and previous.resolve() != self.attack_dir.resolve():
                self.attack_dir.mkdir(parents=True, exist_ok=True)
                for name in INJECTION_FILES:
                    if (previous / name).is_file() and not (self.attack_dir / name).exists():
                        shutil.copy2(previous / name, self.attack_dir / name)
        self.record.resumed.append(resumed)
        CONSOLE.log(
            f"stealth-ns: resumed at step {resumed['step']} "
            f"with {resumed['poison_gaussians']} poison Gaussians"
        )
        self._write_record(views=True)

    # ------------------------------------------------------------------ injection
    def render_depths(self, indices: list[int]) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
        """Rendered z-depth [H, W] and opacity [H, W] of the current model at training views."""
        cameras = self.datamanager.train_dataset.cameras
        depths, alphas = [], []
        for index in indices:
            out = self.model.render_view(cameras[index : index + 1])
            depths.append(out["depth"][..., 0].float().cpu())
            alphas.append(out["accumulation"][..., 0].float().cpu())
        return depths, alphas

    @property
    def support_indices(self) -> list[int]:
        """Every poisoned view's support views (``support_views``), train indices in order."""
        return sorted({i for views in self.support_views.values() for i in views})

    def cameras_with_depth(self, indices: list[int]) -> CameraDepths:
        """Training views ``indices`` with the current model's rendered depth and opacity."""
        cameras = self.datamanager.train_dataset.cameras
        depths, alphas = self.render_depths(indices)
        chosen = cameras[torch.tensor(indices, dtype=torch.long)]
        return CameraDepths(
            viewmats=viewmat_from_c2w(chosen.camera_to_worlds.float()).cpu(),
            Ks=chosen.get_intrinsics_matrices().float().cpu(),
            depths=depths,
            alphas=alphas,
        )

    def innocent_cameras(self) -> CameraDepths:
        """The training views that are neither poisoned nor support views, with their depth and opacity."""
        shown = {v.index for v in self.poison_views} | set(self.support_indices)
        n = len(self.datamanager.train_dataset.cameras)
        return self.cameras_with_depth([i for i in range(n) if i not in shown])

    @torch.no_grad()
    def poison_placement(self) -> PoisonPlacement:
        """Where the density-guided component would put poison Gaussians in the current model (one per
        illusion pixel; nothing is appended). Scene units, nerfstudio's rescaled frame."""
        cfg = self.config.attack
        depths, alphas = self.render_depths([v.index for v in self.poison_views])
        innocent = self.innocent_cameras() if cfg.placement in CAMERA_PLACEMENTS else None
        supports = None
        if self.support_views:
            supports = [self.cameras_with_depth(self.support_views[v.index]) for v in self.poison_views]
        means = self.model.means.detach().cpu().numpy()
        opacities = thread_invariant.sigmoid(self.model.opacities.detach()).squeeze(-1).cpu().numpy()
        return place_poison(
            means,
            opacities,
            self.poison_views,
            depths,
            alphas,
            cfg,
            innocent,
            near_plane=NEAR_PLANE,
            supports=supports,
        )

    def support_targets(self, placement: PoisonPlacement) -> dict[int, tuple[torch.Tensor, torch.Tensor]]:
        """Each support view's training image (float [H, W, 3]) and where the poison covers it ([H, W]
        bool): the placed poison, as injected and drawn opaque, over its clean image
        (:mod:`stealth_ns.attack.support`)."""
        cameras = self.datamanager.train_dataset.cameras
        targets = {}
        for index in self.support_indices:
            cam = cameras[index : index + 1]
            rgb, alpha = render_poison(
                placement.means,
                placement.colors,
                placement.scales,
                viewmat_from_c2w(cam.camera_to_worlds.float())[0],
                cam.get_intrinsics_matrices().float()[0],
                int(cam.width),
                int(cam.height),
            )
            clean = rgb_float(self.datamanager.cached_train[index]["image"])
            targets[index] = (support_target(clean, rgb, alpha), alpha > 0.5)
        return targets

    def support_training_images(
        self, support: dict[int, tuple[torch.Tensor, torch.Tensor]]
    ) -> dict[int, torch.Tensor]:
        """:meth:`support_targets` in the cache's dtype/channels, as :func:`training_target` does for the
        poisoned views (RGBA keeps its alpha, made opaque where the poison covers the view)."""
        cached = self.datamanager.cached_train
        return {i: cached_format(t, cached[i]["image"], covered) for i, (t, covered) in support.items()}

    @torch.no_grad()
    def inject_poison(self, step: int) -> PoisonPlacement:
        """Pipeline callback: place and append one poison Gaussian per illusion pixel."""
        t0 = time.perf_counter()
        cfg = self.config.attack
        model = self.model
        placement = self.poison_placement()
        n_new = placement.means.shape[0]
        if n_new == 0:
            fail(
                f"t_max < t_min for every illusion pixel at step {step}: the rendered surface is nearer than "
                f"t_min {placement.t_min}; lower --pipeline.attack.t-min-fraction or --pipeline.attack.t-min"
            )
        n_before = model.num_points
        model.append_gaussians(placement.means, placement.colors, placement.scales, cfg.poison_opacity)
        support = self.support_targets(placement)
        if support:  # the support views show the poison from now on, noise-free like the poisoned views
            dm = self.datamanager
            dm.set_poison({**dm.poison_targets, **self.support_training_images(support)}, dm.noise)
        placement.timings["total_s"] = time.perf_counter() - t0
        assert self.record is not None
        self.record.injection = injection_entry(placement, step, n_before, self.support_view_names())
        self.record.support_targets = {i: target for i, (target, _) in support.items()}
        self._write_injection_artifacts(placement)
        CONSOLE.log(
            f"stealth-ns: injected {n_new} poison Gaussians at step {step} "
            f"({n_before} -> {model.num_points}; {placement.timings['total_s']:.1f} s)"
        )
        return placement

    # ------------------------------------------------------------------ evaluation
    @torch.no_grad()
    def attack_metrics(self, lpips_nulls: bool = True) -> dict[str, Any]:
        """V-illusory (masked metrics of each poisoned-view render against I_ILL) and the PSNR of
        the innocent training views against their clean images.

        Keys: ``v_illusory_{psnr,ssim,lpips}`` (:func:`stealth_ns.images.metrics.v_illusory` over the poisoned
        views), the same with ``[view name]`` per view, ``innocent_train_psnr``. When LPIPS is
        unavailable and ``lpips_nulls`` is set, ``v_illusory_lpips`` is None and ``lpips_unavailable``
        says why; otherwise keys without a value are left out (training logs take floats only).
        """
        cameras = self.datamanager.train_dataset.cameras
        model = self.model
        per_view = {}
        for v in self.poison_views:
            pred = model.render_view(cameras[v.index : v.index + 1])["rgb"].float().cpu()
            per_view[v.name] = illusion_metrics(pred, v.target, v.mask, model.lpips_metric)
        results: dict[str, Any] = {
            f"v_illusory_{key}[{name}]": value
            for name, metrics in per_view.items()
            for key, value in metrics.items()
            if value is not None
        }
        for key, value in v_illusory(per_view).items():
            if value is not None or (key == "lpips" and lpips_nulls):
                results[f"v_illusory_{key}"] = value
        if results.get("v_illusory_lpips", 0.0) is None:
            results["lpips_unavailable"] = model.lpips_metric.reason
        poisoned = {v.index for v in self.poison_views}
        innocent = []
        for index in range(len(cameras)):
            if index not in poisoned:
                clean = rgb_float(self.datamanager.cached_train[index]["image"])
                innocent.append(
                    psnr(model.render_view(cameras[index : index + 1])["rgb"].float().cpu(), clean)
                )
        if innocent:
            results["innocent_train_psnr"] = float(np.mean(innocent))
        return results

    def get_average_eval_image_metrics(
        self, step: int | None = None, output_path: Path | None = None, get_std: bool = False
    ) -> dict[str, Any]:
        """nerfstudio's held-out (V-test) metrics plus, for an attacked run, ``attack_metrics``."""
        metrics = super().get_average_eval_image_metrics(step=step, output_path=output_path, get_std=get_std)
        if self.poison_views:
            # ns-eval calls without a step and writes JSON (nulls allowed); training logs need floats
            metrics.update(self.attack_metrics(lpips_nulls=step is None))
        return metrics

    # ------------------------------------------------------------------ the viewer's interface
    def split_views(self) -> dict[str, tuple[list[str], Cameras]]:
        """``{"train": (names, cameras), "eval": (names, cameras)}``: every view by split, named as users
        name views (relative to the dataset folder); what the viewer's attack panel lists."""
        data = Path(self.datamanager.config.dataparser.data)
        views = {}
        for split, dataset in (
            ("train", self.datamanager.train_dataset),
            ("eval", self.datamanager.eval_dataset),
        ):
            if dataset is not None:
                views[split] = (dataset_image_names(data, dataset.image_filenames), dataset.cameras)
        return views

    # ------------------------------------------------------------------ artifacts
    def _write_record(self, views: bool = False) -> None:
        if self.attack_dir is not None and self.record is not None:
            self.record.write(self.attack_dir, views=views)

    def _write_injection_artifacts(self, placement: PoisonPlacement) -> None:
        if self.attack_dir is None:
            return
        write_injection_files(
            self.attack_dir, placement.means, placement.colors, placement.grid, placement.kde
        )
        self._write_record(views=bool(self.record and self.record.support_targets))

    def support_view_names(self) -> dict[str, list[str]]:
        """Each poisoned view's support views (``support_views``), by image name."""
        names = self.datamanager.train_image_names
        return {v.name: [names[i] for i in self.support_views.get(v.index, [])] for v in self.poison_views}
