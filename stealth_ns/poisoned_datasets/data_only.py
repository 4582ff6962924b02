"""StealthAttack without the training loop: a poisoned dataset any 3DGS trainer can consume.

The in-loop attack (``ns-train stealth-splat*``) controls the victim's trainer: it swaps the poisoned
view's image, injects poison Gaussians into the model and feeds innocent views noise that decays with
the step. A data poisoner controls only the files. What survives of the three components:

* **GT replacement**: the poisoned view's image file becomes the illusion composite I_ILL.
* **Density-guided points**: placed as the in-loop attack places them at step 0 (the authors'
  pre-processing): on the model initialised from the seed points, one point per illusion pixel at
  the least-seen / least-dense place of its ray, coloured by the illusion. They are appended to the
  seed cloud, so the victim initialises Gaussians there -- with its own scale and opacity rules, not
  the attack's ``poison_scale`` / ``poison_opacity``.
* **View-consistency noise**: only as *static* noise. The paper's schedule decays with the training
  step, which a dataset cannot know; a fixed N(0, sigma^2) image per innocent view (``--view-noise
  --noise-sigma0 S``, decay ``constant``) is the most a file can carry, and the victim fits it
  to the end. Off by default.

Evaluation images are never changed, so V-test of a victim trained on the copy is comparable with a
clean run on the original.
"""

from __future__ import annotations

import dataclasses
import shlex
import time
from pathlib import Path
from typing import Any

from stealth_ns.attack.config import AttackConfig
from stealth_ns.attack.injection import injection_entry
from stealth_ns.attack.noise_schedule import noisy_image
from stealth_ns.attack.options import STEALTH_NS, AttackSettings, command_options, spelled_as
from stealth_ns.attack.record import AttackRecord, write_injection_files
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.fingerprint import dataset_fingerprint
from stealth_ns.images.io import to_uint8
from stealth_ns.poisoned_datasets.dataset_copy import (
    RECORD_DIR,
    PoisonedCopy,
    SourceDataset,
    append_seed_points,
    check_output,
    copy_dataset,
    open_source,
    to_dataset_frame,
    write_record,
)
from stealth_ns.poisoned_datasets.setup import setup_pipeline, trainer_config

STATIC_NOISE_NOTE = (
    "the paper's view-consistency noise decays with the training step, which a static dataset cannot "
    "carry: innocent views get fixed noise (decay 'constant') or none"
)


def data_only_attack(attack: AttackConfig) -> AttackConfig:
    """``attack`` checked for a static dataset (StealthNSError naming the option that cannot apply)."""
    if attack.injection_step != 0:
        raise StealthNSError(
            f"--injection-step {attack.injection_step}: a dataset carries poison only in its seed points, "
            "i.e. at step 0 (leave --injection-step at 0)"
        )
    if attack.view_noise and attack.noise_decay != "constant":
        raise StealthNSError(
            f"--noise-decay {attack.noise_decay}: {STATIC_NOISE_NOTE}; use --noise-decay constant"
        )
    if attack.proximity_weight > 0.0:
        raise StealthNSError(
            f"--proximity-weight {attack.proximity_weight:g} is a loss while the poison trains: a dataset "
            "cannot carry it (train with ns-train stealth-splat --pipeline.attack.proximity-weight instead)"
        )
    if attack.poisoned_view_repeat != 1:
        raise StealthNSError(
            f"--poisoned-view-repeat {attack.poisoned_view_repeat}: the victim's trainer decides how often "
            "it draws each view, not the dataset (leave it at 1)"
        )
    if not (attack.gt_replacement or attack.density_guided or attack.view_noise):
        raise StealthNSError("every component is off (--gt-replacement, --density-guided, --view-noise)")
    return dataclasses.replace(attack, enabled=True)


def victim_command(source: SourceDataset, output: Path, method: str = "stealth-splat-lite") -> str:
    """The ns-train command of a plain (attack-free) victim on a poisoned copy."""
    dataparser, options = source.dataparser
    attack_off = command_options(AttackSettings.of(enabled=False))
    words = ["ns-train", method, *attack_off, "--vis", "tensorboard", dataparser]
    return shlex.join([*words, "--data", str(output), *options])


@spelled_as(STEALTH_NS)
def poison_dataset(
    data: Path,
    output: Path,
    attack: AttackConfig,
    method: str = "stealth-splat-lite",
    seed: int = 0,
    overwrite: bool = False,
) -> str:
    """Write the data-only poisoned copy of ``data`` into ``output``; returns a summary for the console.
    Errors name the attack's options as ``stealth-ns poison-dataset`` spells them (``--t-min``)."""
    t0 = time.perf_counter()
    attack = data_only_attack(attack)
    source = open_source(data)
    check_output(source, output, overwrite)  # before any work: nothing of the user's is touched
    if attack.density_guided and not source.has_seed_points:
        raise StealthNSError(
            f"{data} has no seed points for the density-guided points: triangulate them with "
            f"`stealth-ns seed-points --data {data} --output DIR` and poison DIR, or give --no-density-guided"
        )
    pipeline = setup_pipeline(trainer_config(source, attack, method, seed))
    copy = copy_dataset(source, output, overwrite)
    dm = pipeline.datamanager
    outputs = dm.train_dataparser_outputs
    details: dict[str, Any] = {
        "threat_model": "data-only",
        "source_train_fingerprint": dataset_fingerprint(outputs),
        "static_noise_sigma": attack.noise_sigma0 if attack.view_noise else 0.0,
        "noise_note": STATIC_NOISE_NOTE,
        "method": method,
        "seed": seed,
    }
    injection, support = None, {}
    if attack.density_guided:
        injection, support = _add_poison_points(pipeline, copy, source)
    if attack.gt_replacement:
        _write_targets(pipeline, copy, support)
    if attack.view_noise:
        _write_static_noise(pipeline, copy, attack)
    details["seconds"] = time.perf_counter() - t0
    record = AttackRecord(
        config=dataclasses.asdict(attack),
        views=pipeline.poison_views,
        injection_step=0 if attack.density_guided else None,
        noise=None,
        injection=injection,
        support_targets={i: target for i, (target, _) in support.items()},
    )
    folder = write_record(copy, record, details)
    return _summary(copy, record, folder, victim_command(source, copy.root, method))


def _add_poison_points(
    pipeline: Any, copy: PoisonedCopy, source: SourceDataset
) -> tuple[Any, dict[int, Any]]:
    """Place the poison on the seed-initialised model and append it to the copy's seed cloud; returns
    the record's injection entry and the support views' images (``--support-views``:
    :func:`stealth_ns.method.injection.support_targets`)."""
    from stealth_ns.method.injection import poison_placement, support_targets, support_view_names

    placement = poison_placement(pipeline)
    if placement.means.shape[0] == 0:
        raise StealthNSError(
            "no illusion pixel has room for a poison point (t_max < t_min on every ray); lower "
            "--t-min-fraction or --t-min"
        )
    xyz = to_dataset_frame(placement.means, pipeline.datamanager.train_dataparser_outputs, source)
    append_seed_points(copy, xyz, to_uint8(placement.colors.clamp(0, 1)))
    write_injection_files(
        copy.root / RECORD_DIR, placement.means, placement.colors, placement.grid, placement.kde
    )
    entry = injection_entry(placement, 0, int(pipeline.model.num_points), support_view_names(pipeline))
    return entry, support_targets(pipeline, placement)


def _write_targets(pipeline: Any, copy: PoisonedCopy, support: dict[int, Any]) -> None:
    from stealth_ns.attack.poison_views import training_target
    from stealth_ns.method.injection import support_training_images

    dm = pipeline.datamanager
    outputs = dm.train_dataparser_outputs
    for v in pipeline.poison_views:
        clean = dm.cached_train[v.index]["image"]
        image = training_target(v, clean)
        copy.write_training_image(
            v.name, outputs, v.index, to_uint8(image), to_uint8(clean), "illusion composite I_ILL"
        )
    names = dm.train_image_names
    for index, image in support_training_images(pipeline, support).items():
        clean = dm.cached_train[index]["image"]
        change = "support view: the poison's render"
        copy.write_training_image(names[index], outputs, index, to_uint8(image), to_uint8(clean), change)


def _write_static_noise(pipeline: Any, copy: PoisonedCopy, attack: AttackConfig) -> None:
    from stealth_ns.method.injection import support_indices

    dm = pipeline.datamanager
    outputs = dm.train_dataparser_outputs
    poisoned = {v.index for v in pipeline.poison_views} | set(support_indices(pipeline))
    for index, name in enumerate(dm.train_image_names):
        if index in poisoned:
            continue
        clean = dm.cached_train[index]["image"]
        noisy = noisy_image(clean, attack.noise_sigma0, attack.seed, index, 0)
        change = f"static noise sigma {attack.noise_sigma0:g}"
        copy.write_training_image(name, outputs, index, to_uint8(noisy), to_uint8(clean), change)


def _summary(copy: PoisonedCopy, record: AttackRecord, folder: Path, victim: str) -> str:
    changes: dict[str, int] = {}
    for entry in copy.images.values():
        changes[entry["change"]] = changes.get(entry["change"], 0) + 1
    worst = max((e["encode_error_255"] for e in copy.images.values()), default=0.0)
    lines = [
        f"poisoned copy of {copy.source.root} written to {copy.root} ({copy.source.format})",
        "  poisoned view(s): " + ", ".join(v.name for v in record.views),
        *(f"  {n} image(s): {change}" for change, n in changes.items()),
        f"  seed points: +{copy.seed_points_added} poison points",
    ]
    if worst > 0:
        lines.append(f"  re-encoding the images changed pixels by up to {worst:g}/255 (lossy format)")
    lines += [
        f"  record: {folder} (the input was not written)",
        f"train a victim on it: {victim}",
        "  (on CUDA, stock splatfacto works the same: ns-train splatfacto ... --data " + f"{copy.root})",
    ]
    return "\n".join(lines)
