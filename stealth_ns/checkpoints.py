"""nerfstudio checkpoints (``nerfstudio_models/step-NNNNNNNNN.ckpt``): found and read with one-line errors.

nerfstudio picks the latest checkpoint by parsing every name in the folder (a stray file there is a
``ValueError``), asserts that it exists and lets ``torch.load`` raise on a truncated file. Training
(``--load-dir`` / ``--load-checkpoint``, :mod:`stealth_ns.trainer`) and every command that loads a run
(:func:`stealth_ns.safe_config.safe_eval_setup`, the imported models, the pruned runs of the defences)
go through these two functions instead.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from stealth_ns.errors import StealthNSError

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


def checkpoint_mismatch(
    saved: dict[str, Any], attack: dict[str, Any] | None, images: dict[str, Any], resuming: bool
) -> str | None:
    """Why a checkpoint does not belong to the run loading it, or None.

    ``saved``: what the stealth pipeline stored in the checkpoint (its extra state: ``attack_record``,
    the attack record as JSON, "{}" for a clean run; ``train_images``, the training split's image
    fingerprint :func:`stealth_ns.fingerprint.dataset_fingerprint` as JSON); empty for a checkpoint
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
