"""What the scan reads besides the model, step by step: the cameras alone, or the photos too.

A model with no photos at hand (an official 3DGS output folder scanned on its cameras.json alone) is
scanned by the steps that need the cameras only; those that compare the model with the photos are
skipped, and scan.json's ``photos`` entry (:func:`photo_record`) says which steps ran on what. The
verdict itself (the groups' effect on their views) never reads the photos.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

#: Each step of the scan -> what it reads besides the model: "cameras" or "photos".
STEP_INPUTS: dict[str, str] = {
    "render match": "photos",
    "view-support": "cameras",
    "camera-proximity": "cameras",
    "grad-concentration": "photos",
    "groups": "cameras",
}
"""``render match``: the model's renders of three training views against their photos (no verdict on
a model that does not fit them, :mod:`stealth_ns.scan.fit`); the signals (:mod:`stealth_ns.defences.
posthoc`): blending weights and depths in the training cameras, or a fine-tune against the photos;
``groups``: each group's effect on its view, from renders of the model with and without it."""
SKIPPED = "skipped: needs the photos"


@dataclass(frozen=True)
class PhotoUse:
    """Whether the scan has the photos of the model's training views, and from where."""

    used: bool = True
    origin: str = ""
    """``--data``, ``the run's dataset``, ``cfg_args' source_path``; "" without photos."""
    note: str = ""
    """Where the photos come from, or why there are none, in a sentence."""


def photo_steps(use: PhotoUse, signals: Sequence[str]) -> dict[str, str]:
    """Each step the scan takes with ``signals`` -> "photos", "cameras" or :data:`SKIPPED`."""
    steps = ("render match", *signals, "groups")
    return {s: SKIPPED if STEP_INPUTS[s] == "photos" and not use.used else STEP_INPUTS[s] for s in steps}


def photo_record(use: PhotoUse, signals: Sequence[str]) -> dict[str, Any]:
    """scan.json's ``photos``: ``used``, ``origin``, ``note`` and ``steps`` (:func:`photo_steps`)."""
    return {"used": use.used, "origin": use.origin, "note": use.note, "steps": photo_steps(use, signals)}


def photo_signals_refused(use: PhotoUse, signals: Sequence[str]) -> str | None:
    """The one-line reason to refuse ``signals`` that need the photos when there are none, or None."""
    needing = [s for s in signals if STEP_INPUTS.get(s) == "photos"]
    if use.used or not needing:
        return None
    return (
        f"--signals {needing[0]} fine-tunes the model against the photos, and there are none ({use.note}): "
        "give --data, or leave it out"
    )
