"""nerfstudio checkpoints (``nerfstudio_models/step-NNNNNNNNN.ckpt``): found and read with one-line errors.

nerfstudio picks the latest checkpoint by parsing every name in the folder (a stray file there is a
``ValueError``), asserts that it exists and lets ``torch.load`` raise on a truncated file. Training
(``--load-dir`` / ``--load-checkpoint``, :mod:`stealth_ns.method.trainer`) and every command that loads a run
(:func:`stealth_ns.method.safe_config.safe_eval_setup`, the imported models, the pruned runs of the defences)
go through these two functions instead. ns-train's checkpoints are written by :func:`save_checkpoint`,
whole or not at all. One training at a time writes a run folder, and none writes into another run's
(:func:`claim_run_folder`), and a resume is refused a checkpoint of another model shape
(:func:`shape_mismatch`, naming the options that differ: :func:`option_changes`).
"""

from __future__ import annotations

import dataclasses
import os
import re
from pathlib import Path
from typing import Any

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.json_io import atomic_path

_NAME = re.compile(r"^step-(\d+)\.ckpt$")
#: What every checkpoint holds (a defence's pruned run writes only these).
MODEL_KEYS = ("step", "pipeline")
#: What resuming training needs besides (``Trainer.save_checkpoint``; "schedulers" is optional).
TRAINING_KEYS = (*MODEL_KEYS, "optimizers", "scalers")


def checkpoint_steps(folder: Path) -> dict[int, Path]:
    """``{step: path}`` of the ``step-N.ckpt`` files in ``folder`` (other names ignored)."""
    if not folder.is_dir():
        return {}
    found = {}
    for path in folder.iterdir():
        match = _NAME.match(path.name)
        if match and path.is_file():
            found[int(match.group(1))] = path
    return found


def find_checkpoint(folder: Path, step: int | None = None, flag: str = "--load-dir") -> Path:
    """The checkpoint of ``step`` (None: the latest) in ``folder``; StealthNSError naming ``flag``
    when the folder or the checkpoint is missing."""
    folder = Path(folder)
    if not folder.is_dir():
        raise StealthNSError(f"{flag} {folder}: no such folder (a run's nerfstudio_models/)")
    steps = checkpoint_steps(folder)
    if not steps:
        raise StealthNSError(f"{flag} {folder} holds no checkpoint (step-N.ckpt): was the run trained?")
    if step is None:
        return steps[max(steps)]
    if step not in steps:
        have = ", ".join(str(s) for s in sorted(steps)[-5:])
        raise StealthNSError(f"{flag} {folder} has no checkpoint of step {step} (it has steps {have})")
    return steps[step]


def read_checkpoint(path: Path, keys: tuple[str, ...] = MODEL_KEYS) -> dict[str, Any]:
    """``torch.load`` of a checkpoint file (tensors only) that holds ``keys``, with a one-line error
    for a missing, truncated or foreign file."""
    import torch

    path = Path(path)
    if not path.is_file():
        raise StealthNSError(f"checkpoint {path} does not exist")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch's unpickler raises anything (IndexError, EOFError, ...) on garbage
        reason = (str(err).splitlines() or [type(err).__name__])[0].split(". ")[0]
        raise StealthNSError(
            f"cannot read checkpoint {path} ({reason}): the file is truncated or not a nerfstudio "
            "checkpoint; train again or resume from an earlier one (--load-step)"
        ) from None
    missing = [k for k in keys if not isinstance(state, dict) or k not in state]
    if missing:
        what = "a nerfstudio checkpoint" if keys == MODEL_KEYS else "a checkpoint training can resume from"
        raise StealthNSError(f"{path} is not {what} (no {', '.join(missing)})")
    return state


class _WriteRecorder:
    """A file's ``write`` that keeps the OSError it raised: torch.save reports a failed write as a
    RuntimeError of its zip writer ("unexpected pos ..."), without the errno."""

    def __init__(self, file: Any) -> None:
        self.file, self.error = file, None

    def write(self, data: Any) -> int:
        try:
            return self.file.write(data)
        except OSError as err:
            self.error = err
            raise

    def flush(self) -> None:
        self.file.flush()


def save_checkpoint(path: Path, state: dict[str, Any]) -> Path:
    """``torch.save`` of ``state`` to ``path`` through a temporary file beside it
    (:func:`~stealth_ns.foundation.json_io.atomic_path`, a name :func:`checkpoint_steps` does not read): a
    save cut short (a full disk) leaves no ``step-N.ckpt``, only the checkpoints there were before.

    Raises:
        StealthNSError: ``cannot write PATH: No space left on device`` (the failed write's reason).
    """
    import torch

    path = Path(path)
    with atomic_path(path) as tmp, tmp.open("wb") as f:
        out = _WriteRecorder(f)
        try:
            torch.save(state, out)
        except RuntimeError:
            if out.error is None:
                raise
            raise out.error from None
    return path


def checkpoint_mismatch(
    saved: dict[str, Any], attack: dict[str, Any] | None, images: dict[str, Any], resuming: bool
) -> str | None:
    """Why a checkpoint does not belong to the run loading it, or None.

    ``saved``: what the stealth pipeline stored in the checkpoint (its extra state: ``attack_record``,
    the attack record as JSON, "{}" for a clean run; ``train_images``, the training split's image
    fingerprint :func:`stealth_ns.foundation.fingerprint.dataset_fingerprint` as JSON); empty for a checkpoint
    from before these were stored, which is not checked. ``attack``: the run's attack options
    (``json_safe`` of its ``AttackConfig``), None with the attack off. ``images``: the fingerprint of the
    training split the run has now. ``resuming``: training goes on from it (else: a run loaded for
    evaluation), which decides the advice.
    """
    import json

    elsewhere = "the run folder holds another run's checkpoint"
    if saved.get("train_images"):
        theirs = json.loads(saved["train_images"])
        if theirs.get("images") != images.get("images") or theirs.get("n_images") != images.get("n_images"):
            return (
                f"its model was trained on other images ({theirs.get('n_images')}) than the dataset's "
                f"training split ({images.get('n_images')} images): another scene's run, or the dataset "
                "changed since"
            )
    if "attack_record" not in saved:
        return None
    record = json.loads(saved["attack_record"] or "{}")
    if attack is not None and not record:
        advice = (
            "resuming cannot add the attack (the poison is injected when training starts): train the "
            "attacked run from scratch"
            if resuming
            else f"the run's config has the attack on: {elsewhere}"
        )
        return f"it is a clean run's (no attack record); {advice}"
    if attack is None and record:
        advice = (
            "this run has the attack off (--pipeline.attack.enabled False): resume it with its own options"
            if resuming
            else f"the run's config has the attack off: {elsewhere}"
        )
        return f"it is an attacked run's; {advice}"
    options = record.get("config") or {}
    changed = sorted(k for k, v in options.items() if attack and k in attack and attack[k] != v)
    if changed:
        said = ", ".join(
            f"--pipeline.attack.{k.replace('_', '-')} {options[k]!r} (now {attack[k]!r})"  # type: ignore[index]
            for k in changed[:4]
        )
        advice = "resume it with the options it was trained with" if resuming else elsewhere
        return f"its attack had other options: {said}; {advice}"
    return None


# ---------------------------------------------------------------------------------- one run per folder
#: The file in a run folder that ns-train locks while it trains there (it holds the process id).
LOCK_FILE = ".ns-train.lock"
_HELD: dict[Path, int] = {}  # lock file -> open descriptor, held until this process ends


def _in_use(folder: Path, pid: str) -> StealthNSError:
    return StealthNSError(
        f"the run folder {folder} is in use by another training (process {pid or '?'}): give this one "
        "another --timestamp (or --experiment-name, --output-dir)"
    )


def lock_run_folder(folder: Path) -> None:
    """Hold an exclusive lock (``flock``) on ``folder``'s :data:`LOCK_FILE` until this process ends;
    a process that holds it already keeps it. StealthNSError naming the process that holds it.

    Where the file system has no locks (some network mounts, Windows) nothing is locked, and
    :func:`run_folder_conflict` alone keeps two runs apart once one has written its config.
    """
    try:
        import fcntl
    except ImportError:
        return
    lock = Path(folder) / LOCK_FILE
    held = _HELD.pop(lock, None)
    if held is not None:
        try:
            same = os.path.samestat(os.fstat(held), os.stat(lock))
        except OSError:  # the folder was removed and made again in this process
            same = False
        if same:
            _HELD[lock] = held
            return
        os.close(held)
    fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        pid = os.pread(fd, 20, 0).decode(errors="replace").strip()
        os.close(fd)
        raise _in_use(folder, pid) from None
    except OSError:  # no locks on this file system
        os.close(fd)
        return
    os.ftruncate(fd, 0)
    os.pwrite(fd, str(os.getpid()).encode(), 0)
    _HELD[lock] = fd


def run_folder_holder(folder: Path) -> str | None:
    """The process id of another process training in ``folder`` (holding its lock), else None; nothing
    is written."""
    lock = Path(folder) / LOCK_FILE
    if lock in _HELD or not lock.is_file():
        return None
    try:
        import fcntl

        fd = os.open(lock, os.O_RDONLY)
    except (ImportError, OSError):
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return os.pread(fd, 20, 0).decode(errors="replace").strip() or "?"
    except OSError:
        return None
    finally:
        os.close(fd)  # a lock it took goes with it
    return None


def claim_run_folder(folder: Path, resume_from: Path | None) -> None:
    """Make ``folder`` this training's run folder until the process ends (:func:`lock_run_folder`), or
    StealthNSError with one line when another training holds it or it holds another run
    (:func:`run_folder_conflict`), in which case nothing is written there."""
    why = run_folder_conflict(folder, resume_from)
    if why is not None:
        pid = run_folder_holder(folder)
        raise StealthNSError(why) if pid is None else _in_use(folder, pid)
    lock_run_folder(folder)
    why = run_folder_conflict(folder, resume_from)  # another training's, written before this one locked
    if why is not None:
        raise StealthNSError(why)


def run_folder_conflict(folder: Path, resume_from: Path | None) -> str | None:
    """Why training into the run folder ``folder`` would mix two runs, or None: it holds a run's
    ``config.yml`` or checkpoints and this training is not that run resumed (``resume_from``: the
    ``--load-dir`` folder or ``--load-checkpoint`` file, None for a fresh start)."""
    folder = Path(folder)
    held = [p.name for p in [folder / "config.yml"] if p.is_file()]
    held += [
        f"nerfstudio_models/{p.name}"
        for _, p in sorted(checkpoint_steps(folder / "nerfstudio_models").items())
    ]
    if not held:
        return None
    if resume_from is not None and Path(os.path.realpath(resume_from)).is_relative_to(
        os.path.realpath(folder)
    ):
        return None
    shown = ", ".join(held[:3]) + (f" and {len(held) - 3} more" if len(held) > 3 else "")
    return (
        f"the run folder {folder} already holds a run ({shown}): a second run there would mix its files "
        f"with that one's; give this one another --timestamp (or --experiment-name, --output-dir), or "
        f"continue that run with --load-dir {folder / 'nerfstudio_models'}"
    )


# ---------------------------------------------------------------------------------- resuming another model
def _shape(shape: tuple[int, ...], rows: bool) -> str:
    return "[" + ", ".join(["N", *map(str, shape[1:])] if rows else map(str, shape)) + "]"


def shape_mismatch(saved: dict[str, Any], current: dict[str, Any]) -> str | None:
    """How a tensor of a checkpoint's pipeline state ``saved`` differs in shape from the model's state
    ``current`` (the number of Gaussians, the rows of ``gauss_params``, aside), or None. Tensors only one
    of them has are left to nerfstudio, which loads the rest."""
    for key in sorted(saved.keys() & current.keys()):
        old, new = getattr(saved[key], "shape", None), getattr(current[key], "shape", None)
        if old is None or new is None:
            continue
        old, new, rows = tuple(old), tuple(new), ".gauss_params." in f".{key}"
        if (old[1:], len(old)) != (new[1:], len(new)) or (not rows and old != new):
            name = key.removeprefix("_model.")
            return f"its {name} is {_shape(old, rows)}, this run's {_shape(new, rows)}"
    return None


def option_changes(saved: Any, current: Any, prefix: str) -> list[str]:
    """``PREFIX.OPTION OLD (now NEW)`` for each option of the dataclass ``current`` (nested ones by
    their own options) whose value differs in ``saved``, as ns-train spells the flags."""
    changes = []
    for field in dataclasses.fields(current):
        if field.name.startswith("_"):
            continue
        old, new = getattr(saved, field.name, None), getattr(current, field.name)
        if old == new:
            continue
        flag = f"{prefix}.{field.name.replace('_', '-')}"
        if dataclasses.is_dataclass(new) and type(old) is type(new):
            changes += option_changes(old, new, flag)
        else:
            changes.append(f"{flag} {old!r} (now {new!r})")
    return changes
