"""nerfstudio's trainer with a checked resume: ``--load-dir`` / ``--load-checkpoint`` give one line, not a
traceback, for a missing folder, a missing step, a stray file in ``nerfstudio_models/`` or a truncated
checkpoint (:mod:`stealth_ns.method.checkpoints`). Whether the checkpoint belongs to this run -- its scene,
its attack -- the pipeline checks when it loads the state (``StealthPipeline.load_pipeline``). Its
TensorBoard images are encoded faster (:mod:`stealth_ns.method.tensorboard_images`). A write the environment
refuses (a full disk, a read-only ``--output-dir``) stops it with one line naming the file, and a checkpoint
is written whole or not at all (:func:`stealth_ns.method.checkpoints.save_checkpoint`). One training at a time
writes a run folder, and never into another run's; a resume is refused a checkpoint of another model
shape naming the option that differs, and writes its config.yml only once the checkpoint has loaded.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import yaml
from nerfstudio.engine.trainer import Trainer, TrainerConfig
from nerfstudio.utils.decorators import check_main_thread
from nerfstudio.utils.rich_utils import CONSOLE

from stealth_ns.foundation.errors import StealthNSError, environment_error, fail, write_error
from stealth_ns.foundation.json_io import write_text_atomic
from stealth_ns.method.checkpoints import (
    TRAINING_KEYS,
    checkpoint_steps,
    claim_run_folder,
    find_checkpoint,
    option_changes,
    read_checkpoint,
    save_checkpoint,
    shape_mismatch,
)
from stealth_ns.method.tensorboard_images import use_fast_png


@dataclass
class StealthTrainerConfig(TrainerConfig):
    """``TrainerConfig`` whose trainer checks the checkpoint it resumes from."""

    _target: type = field(default_factory=lambda: StealthTrainer)

    def save_config(self, resumed: bool = False) -> None:
        """nerfstudio's ``config.yml``, written whole or not at all; one line (no traceback) when the run
        folder cannot be written. The run folder is claimed first (:meth:`claim_run_folder`); a resume
        writes it once its checkpoint has loaded (``resumed``), so a refused one leaves the run as it was."""
        base_dir = self.get_base_dir()
        try:
            base_dir.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            fail(write_error(base_dir, err))
        if not resumed and not self.claim_run_folder():  # resumed: claimed by the first call (ns-train's)
            return
        CONSOLE.log(f"Saving config to: {base_dir / 'config.yml'}")
        try:
            write_text_atomic(base_dir / "config.yml", yaml.dump(self))
        except StealthNSError as err:
            fail(err)

    def claim_run_folder(self) -> bool:
        """The run folder made this process's, or one line when another training holds it or it holds
        another run (:func:`~stealth_ns.method.checkpoints.claim_run_folder`); False for a resume
        (``--load-dir`` / ``--load-checkpoint``)."""
        resume_from = self.load_dir if self.load_dir is not None else self.load_checkpoint
        try:
            claim_run_folder(self.get_base_dir(), resume_from)
        except StealthNSError as err:
            fail(err)
        except OSError as err:
            fail(write_error(self.get_base_dir(), err))
        return resume_from is None


class StealthTrainer(Trainer):
    """``Trainer`` with :meth:`_load_checkpoint` reading through :mod:`stealth_ns.method.checkpoints`."""

    def setup(self, test_mode: Literal["test", "val", "inference"] = "val") -> None:
        with self._environment_errors():
            super().setup(test_mode)
        use_fast_png()

    def train(self) -> None:
        with self._environment_errors():
            super().train()

    @contextlib.contextmanager
    def _environment_errors(self) -> Iterator[None]:
        """A write the environment refused (full disk, read-only folder) or a StealthNSError raised by
        the code below (a one-line write error) stops ns-train with one line instead of a traceback."""
        _quiet_thread_write_errors()
        try:
            yield
        except StealthNSError as err:
            fail(err)
        except OSError as err:
            line = environment_error(err, self.base_dir)
            if line is None:
                raise
            fail(line)

    @check_main_thread
    def save_checkpoint(self, step: int) -> None:
        """nerfstudio's checkpoint, written whole or not at all: a save cut short (a full disk) leaves
        no ``step-N.ckpt`` and stops ns-train with one line; older checkpoints are removed
        (``--save-only-latest-checkpoint``) only once the new one is complete."""
        path = self.checkpoint_dir / f"step-{step:09d}.ckpt"
        pipeline = self.pipeline.module if hasattr(self.pipeline, "module") else self.pipeline
        state = {
            "step": step,
            "pipeline": pipeline.state_dict(),
            "optimizers": {k: v.state_dict() for (k, v) in self.optimizers.optimizers.items()},
            "schedulers": {k: v.state_dict() for (k, v) in self.optimizers.schedulers.items()},
            "scalers": self.grad_scaler.state_dict(),
        }
        try:
            self.checkpoint_dir.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            fail(write_error(self.checkpoint_dir, err))
        try:
            save_checkpoint(path, state)
        except StealthNSError as err:
            fail(err)
        if self.config.save_only_latest_checkpoint:
            for other in checkpoint_steps(self.checkpoint_dir).values():
                if other != path:
                    other.unlink()

    def _load_checkpoint(self) -> None:
        config = self.config
        try:
            if config.load_dir is not None:
                path = find_checkpoint(config.load_dir, config.load_step)
            elif config.load_checkpoint is not None:
                path = config.load_checkpoint
            else:
                CONSOLE.print("No Nerfstudio checkpoint to load, so training from scratch.")
                return
            state = read_checkpoint(path, TRAINING_KEYS)
        except StealthNSError as err:
            fail(err)
        self._start_step = int(state["step"]) + 1
        why = shape_mismatch(state["pipeline"], self.pipeline.state_dict())
        if why is not None:
            fail(f"cannot resume from {path}: {why}{_changed_model_options(config, Path(path))}")
        self.pipeline.load_pipeline(state["pipeline"], state["step"])
        self.optimizers.load_optimizers(state["optimizers"])
        if "schedulers" in state and config.load_scheduler:
            self.optimizers.load_schedulers(state["schedulers"])
        self.grad_scaler.load_state_dict(state["scalers"])
        CONSOLE.print(f"Done loading Nerfstudio checkpoint from {path}")
        config.save_config(resumed=True)


def _changed_model_options(config: TrainerConfig, checkpoint: Path) -> str:
    """``; its run was trained with --pipeline.model.sh-degree 3 (now 1) ...``: the model options that
    differ from the config.yml of the run ``checkpoint`` belongs to ("" when it has none to read)."""
    from stealth_ns.method.safe_config import load_config

    try:
        saved = load_config(checkpoint.parent.parent / "config.yml").pipeline.model
        changes = option_changes(saved, config.pipeline.model, "--pipeline.model")
    except (StealthNSError, AttributeError, TypeError):  # no readable config beside it: the shapes say it
        return ""
    if not changes:
        return ""
    return f"; its run was trained with {', '.join(changes[:4])}: resume with the options it was trained with"


def _quiet_thread_write_errors() -> None:
    """TensorBoard writes its events in a thread, which prints a traceback when the disk is full; the
    training thread gets the same error at its next event and ns-train says it in one line: so a write
    error the environment caused is not printed from a thread (any other error still is)."""
    previous = threading.excepthook
    if getattr(previous, "stealth_ns_quiet", False):
        return

    def hook(args: threading.ExceptHookArgs) -> None:
        if not (isinstance(args.exc_value, OSError) and environment_error(args.exc_value) is not None):
            previous(args)

    hook.stealth_ns_quiet = True  # type: ignore[attr-defined]
    threading.excepthook = hook
