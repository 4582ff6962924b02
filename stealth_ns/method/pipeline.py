"""``StealthPipeline``: nerfstudio's VanillaPipeline with the attack built in. This module is the
nerfstudio glue; the attack's parts are in their own modules.

At construction it checks that the model starts from seed points
(:func:`~stealth_ns.datasets.seed_check.check_injection_seed_points`), resolves the poisoned views and
their targets (:mod:`stealth_ns.attack.poison_views`) and the support views, and fails with a one-line
error on bad input before any training starts. When training starts (``get_training_callbacks``) it
hands the datamanager the poisoned targets and the noise schedule, writes the attack record, and
registers the density-guided injection (:mod:`stealth_ns.method.injection`). Checkpoints carry the
record, which a resumed run continues; a checkpoint of other images or another attack is refused.
Evaluation adds the attack's metrics (:mod:`stealth_ns.method.attack_metrics`) to nerfstudio's, and
``split_views`` is what the viewer's panel lists.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import shutil
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
from stealth_ns.attack.poison_views import build_poison_views, training_target
from stealth_ns.attack.proximity_term import draw_points, proximity_hinge
from stealth_ns.attack.record import INJECTION_FILES, AttackRecord, PoisonView
from stealth_ns.attack.validation import validate_attack_config
from stealth_ns.attack.views import nearest_views
from stealth_ns.datasets.background import uniform_background
from stealth_ns.datasets.check import transforms_path
from stealth_ns.datasets.seed_check import check_injection_seed_points
from stealth_ns.foundation.errors import StealthNSError, fail
from stealth_ns.foundation.fingerprint import dataset_fingerprint, record_fingerprint
from stealth_ns.foundation.json_io import json_safe
from stealth_ns.images.io import to_uint8
from stealth_ns.method.attack_metrics import attack_metrics
from stealth_ns.method.camera_geometry import CameraGeometry, camera_geometry
from stealth_ns.method.checkpoints import checkpoint_mismatch
from stealth_ns.method.datamanager import NoiseSpec, StealthDataManager, dataset_image_names
from stealth_ns.method.injection import inject_poison
from stealth_ns.method.model import StealthSplatModel
from stealth_ns.method.poison_schedule import poison_schedule
from stealth_ns.method.viewer import StealthAttackPanel


@dataclass
class StealthPipelineConfig(VanillaPipelineConfig):
    """Datamanager, model, and the attack (``--pipeline.attack.*``)."""

    _target: type = field(default_factory=lambda: StealthPipeline)
    attack: AttackConfig = field(default_factory=AttackConfig)
    """StealthAttack settings."""


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
            # chosen (and the compiled kernels built after an update) now, so that no training step or
            # the injection's timing includes the build
            _ = self.model.rasterizer_backend
        self.poison_views: list[PoisonView] = []
        self.support_views: dict[int, list[int]] = {}  # poisoned view -> its support views (train indices)
        self.attack_dir: Path | None = None
        self.record: AttackRecord | None = None  # set when training starts (or resumes)
        self._restored_record: dict[str, Any] | None = None  # attack.json content, from a loaded checkpoint
        self._loaded_step = -1
        self._saved_state: dict[str, Any] = {}  # the extra state of a loaded checkpoint
        self.stealth_attack = StealthAttackPanel(self)  # the viewer's panel; inert without a viewer
        self._proximity_cameras: CameraGeometry | None = None  # the white-box term's, once it applies
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
        dm = self.datamanager
        try:
            if cfg.density_guided:
                self._check_seed_points()
            self.poison_views = build_poison_views(
                cfg, dm.train_image_names, dm.train_dataset.cameras, lambda i: dm.cached_train[i]["image"]
            )
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

    def _check_seed_points(self) -> None:
        """StealthNSError unless the model starts from seed points
        (:func:`~stealth_ns.datasets.seed_check.check_injection_seed_points`)."""
        data = getattr(self.datamanager.config.dataparser, "data", None)
        transforms = None if data is None else transforms_path(Path(data))
        points = self.model.seed_points[0] if self.model.seed_points is not None else None
        check_injection_seed_points(points, self.model.config.random_init, transforms, data)

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
        one, :func:`~stealth_ns.method.poison_schedule.poison_schedule`); stop with a one-line error when
        the injection step lies past the run's end."""
        cfg = self.config.attack
        max_steps = attrs.trainer.config.max_num_iterations if attrs.trainer is not None else 30_000
        try:
            noise = poison_schedule(cfg, self.injection_step, max_steps, restored)
        except StealthNSError as err:
            fail(err)
        targets = {}
        if cfg.gt_replacement:
            for v in self.poison_views:
                targets[v.index] = training_target(v, self.datamanager.cached_train[v.index]["image"])
        self.datamanager.set_poison(targets, noise)
        self.datamanager.set_view_repeat(cfg.poisoned_view_repeat, cfg.seed)
        return noise

    def _injection_callbacks(self) -> list[TrainingCallback]:
        """The injection, unless the record says it happened (a resumed run)."""
        if not self.config.attack.density_guided or (self.record is not None and self.record.injection):
            return []
        return [
            TrainingCallback(
                where_to_run=[TrainingCallbackLocation.BEFORE_TRAIN_ITERATION],
                func=functools.partial(inject_poison, self),
                iters=(self.injection_step,),
            )
        ]

    def get_train_loss_dict(self, step: int) -> tuple[Any, dict[str, Any], dict[str, Any]]:
        """nerfstudio's, plus the white-box term ``poison_proximity`` (``proximity_weight``) once poison
        Gaussians exist."""
        applies = self._proximity_applies()  # its cameras' renders before the step's own forward pass
        outputs, losses, metrics = super().get_train_loss_dict(step)
        if applies:
            losses["poison_proximity"] = self._proximity_term(step)
        return outputs, losses, metrics

    def _proximity_applies(self) -> bool:
        """Whether the white-box term applies now (on, after the injection, poison left); the first
        time, every training camera's median rendered depth is measured for it (once per process)."""
        cfg = self.config.attack
        if not cfg.enabled or cfg.proximity_weight <= 0.0 or self.record is None or not self.record.injection:
            return False
        if not bool(self.model.poison_mask.any()):
            return False
        if self._proximity_cameras is None:
            cameras = self.datamanager.train_dataset.cameras
            self._proximity_cameras = camera_geometry(self.model, cameras, desc="scene depth")
        return True

    def _proximity_term(self, step: int) -> torch.Tensor:
        """``proximity_weight`` times :func:`~stealth_ns.attack.proximity_term.proximity_hinge` of the
        poison Gaussians (a seeded draw of them per step) against every training camera."""
        cfg, geometry = self.config.attack, self._proximity_cameras
        assert geometry is not None
        poison = self.model.poison_mask.reshape(-1).nonzero().flatten()
        drawn = draw_points(poison.numel(), step, cfg.seed)
        means = self.model.means[poison if drawn is None else poison[drawn.to(poison.device)]]
        as_tensor = functools.partial(torch.as_tensor, device=means.device, dtype=means.dtype)
        hinge = proximity_hinge(
            means,
            as_tensor(geometry.viewmats),
            as_tensor(geometry.Ks),
            as_tensor(geometry.sizes),
            as_tensor(geometry.scene_depths),
            cfg.proximity_target,
        )
        return cfg.proximity_weight * hinge

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

    # ------------------------------------------------------------------ evaluation
    def get_average_eval_image_metrics(
        self, step: int | None = None, output_path: Path | None = None, get_std: bool = False
    ) -> dict[str, Any]:
        """nerfstudio's held-out (V-test) metrics plus, for an attacked run, the attack's
        (:func:`~stealth_ns.method.attack_metrics.attack_metrics`)."""
        metrics = super().get_average_eval_image_metrics(step=step, output_path=output_path, get_std=get_std)
        if self.poison_views:
            # ns-eval calls without a step and writes JSON (nulls allowed); training logs need floats
            metrics.update(
                attack_metrics(self.model, self.datamanager, self.poison_views, lpips_nulls=step is None)
            )
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
