"""The attack record: what the attack did to a run, written once by the pipeline, read by every tool.

A run's ``<run>/attack/`` folder holds

* ``attack.json``: the attack's settings, the poisoned views (name, training index, camera, mask size),
  the injection (step, Gaussians placed per view, near bounds, how many innocent views see the poison,
  the density grid) with its timings, and where the run was resumed;
* ``views.npz``: each poisoned view's illusion target I_ILL (float32 ``[H, W, 3]`` in [0, 1], exactly as
  trained and scored) and mask (bool ``[H, W]``), keys ``target_NNNN`` / ``mask_NNNN``;
* ``viewNNNN_target.png`` / ``viewNNNN_mask.png``: the same as 8-bit pictures, to look at;
* ``poison_points.ply`` and ``density_grid.npz``, written at the injection.

:class:`AttackRecord` is that folder as a typed object: :meth:`AttackRecord.write` and
:meth:`AttackRecord.read` are the only code that knows the file names and JSON keys. The JSON keys are
those of the first version, so records of older runs still read (when ``views.npz`` is missing their
targets come from the views the loaded pipeline rebuilt, else from the PNGs; their cameras from the
dataset when the JSON has none).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from stealth_ns.attack.density import DensityGrid
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.json_io import json_safe, write_npz_atomic, write_text_atomic
from stealth_ns.images.io import read_image, save_png, to_float32

RECORD_FILE = "attack.json"
VIEWS_FILE = "views.npz"
POISON_POINTS_FILE = "poison_points.ply"
DENSITY_GRID_FILE = "density_grid.npz"
#: Files of the injection that a resumed run carries over from the run it resumed.
INJECTION_FILES = (POISON_POINTS_FILE, DENSITY_GRID_FILE)


class RecordError(StealthNSError):
    """A run's attack record is missing or unreadable (one line, naming the file)."""


@dataclass
class PoisonView:
    """One poisoned training view: camera, illusion mask and target colours."""

    index: int  # training-view index
    name: str  # image name, as ``datamanager.train_image_names``
    c2w: Tensor  # [3, 4] OpenGL camera-to-world, nerfstudio's rescaled scene units
    fx: float  # focal lengths and principal point, pixels
    fy: float
    cx: float
    cy: float
    mask: Tensor  # [H, W] bool, illusion pixels
    target: Tensor  # [H, W, 3] float32 in [0, 1], the illusion composite I_ILL

    def camera_json(self) -> dict[str, Any]:
        return {
            "c2w": [[float(x) for x in row] for row in self.c2w.tolist()],
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
        }


@dataclass
class Injection:
    """The density-guided injection as it happened (``attack.json``'s injection keys).

    Per-view dicts are keyed by view name. Distances are in nerfstudio's rescaled scene units.
    """

    injected_at_step: int
    n_gaussians_before: int  # Gaussians in the model just before
    n_poison_gaussians: int  # poison Gaussians appended
    poison_per_view: dict[str, int]
    invalid_rays_per_view: dict[str, int]  # illusion pixels whose ray had t_max < t_min
    t_min_per_view: dict[str, float]  # near bound of the search
    t_min_unseen_per_view: dict[str, float]  # view-aware: near bound for poison no innocent view sees
    innocent_views_seeing_poison: dict[str, float]  # all but kde: mean innocent views seeing a poison
    poison_unseen_fraction: dict[str, float]  # all but kde: share of poison no innocent view sees
    density_grid: dict[str, Any]  # shape [3], voxel_size, origin [3]
    # density_kde_s, ray_search_s (of it: cpu_kernels_load_s, visibility_s the view counts made
    # outside the compiled search), total_s
    timings_s: dict[str, float]
    # support_views > 0: poisoned view -> its support views, and how many see a poison Gaussian (mean)
    support_views: dict[str, list[str]] = field(default_factory=dict)
    support_views_seeing_poison: dict[str, float] = field(default_factory=dict)
    # depth_floor > 0: illusion pixels left without poison, their ray having no sample at the floor
    rays_below_depth_floor_per_view: dict[str, int] = field(default_factory=dict)


@dataclass
class AttackRecord:
    """Everything the attack did to one run (see the module docstring)."""

    config: dict[str, Any]  # the AttackConfig, as JSON
    views: list[PoisonView]
    injection_step: int | None  # planned step of the injection (None: no density-guided component)
    noise: dict[str, Any] | None  # the noise schedule (sigma0, decay, total_steps, seed), None when off
    injection: Injection | None = None
    resumed: list[dict[str, Any]] = field(default_factory=list)  # {"step", "poison_gaussians", "from"}
    # a poisoned copy of a dataset (stealth-ns poison-dataset / ipa-poison): threat model, source dataset
    # and its training fingerprint, the images written, the seed points added; None for a run's own attack
    poisoned_dataset: dict[str, Any] | None = None
    # support views (``support_views``): train index -> its training image from the injection on,
    # [H, W, 3] float32 in [0, 1] (views.npz / viewNNNN_support.png)
    support_targets: dict[int, Tensor] = field(default_factory=dict)

    @property
    def n_poison_gaussians(self) -> int:
        """Poison Gaussians appended at the injection (0 before it)."""
        return 0 if self.injection is None else self.injection.n_poison_gaussians

    # ------------------------------------------------------------------ JSON
    def to_json(self) -> dict[str, Any]:
        """``attack.json``'s content (flat keys, as the first version wrote them)."""
        data: dict[str, Any] = {
            "config": json_safe(self.config),
            "poisoned_views": [
                {"index": v.index, "name": v.name, "mask_pixels": int(v.mask.sum()), **v.camera_json()}
                for v in self.views
            ],
            "injection_step": self.injection_step,
            "noise": json_safe(self.noise),
            "n_poison_gaussians": self.n_poison_gaussians,
        }
        if self.injection is not None:
            data.update(json_safe(dataclasses.asdict(self.injection)))
        if self.resumed:
            data["resumed"] = json_safe(self.resumed)
        if self.poisoned_dataset is not None:
            data["poisoned_dataset"] = json_safe(self.poisoned_dataset)
        return data

    def dumps(self) -> str:
        """The record as one JSON string (kept in checkpoints, so a resumed run continues it)."""
        return json.dumps(self.to_json(), sort_keys=True)

    @classmethod
    def from_json(cls, data: dict[str, Any], views: list[PoisonView]) -> AttackRecord:
        """The record from ``attack.json``'s content and the views (whose targets live outside the JSON)."""
        names = {f.name for f in dataclasses.fields(Injection)}
        injection = None
        if "injected_at_step" in data:
            injection = Injection(**{k: data.get(k, {}) for k in names})
        return cls(
            config=dict(data.get("config") or {}),
            views=views,
            injection_step=data.get("injection_step"),
            noise=data.get("noise"),
            injection=injection,
            resumed=list(data.get("resumed") or []),
            poisoned_dataset=data.get("poisoned_dataset"),
        )

    # ------------------------------------------------------------------ files
    def write(self, attack_dir: Path, views: bool = True) -> None:
        """Write ``attack.json`` (with ``views`` also ``views.npz`` and the view PNGs) into ``attack_dir``."""
        attack_dir.mkdir(parents=True, exist_ok=True)
        if views:
            arrays = {}
            for v in self.views:
                key, mask = f"{v.index:04d}", v.mask.detach().cpu().numpy().astype(bool)
                arrays[f"target_{key}"] = v.target.detach().cpu().float().numpy()
                arrays[f"mask_{key}"] = mask
                save_png(attack_dir / f"view{key}_target.png", v.target)
                save_png(attack_dir / f"view{key}_mask.png", mask)
            for index, image in self.support_targets.items():
                arrays[f"support_{index:04d}"] = image.detach().cpu().float().numpy()
                save_png(attack_dir / f"view{index:04d}_support.png", image)
            write_npz_atomic(attack_dir / VIEWS_FILE, arrays)
        write_text_atomic(attack_dir / RECORD_FILE, json.dumps(self.to_json(), indent=2, sort_keys=True))

    @classmethod
    def read(cls, attack_dir: Path, cameras: Any = None, rebuilt: Sequence[PoisonView] = ()) -> AttackRecord:
        """The record of the run whose attack folder is ``attack_dir``.

        Args:
            attack_dir: ``<run>/attack``.
            cameras: the run's training cameras (nerfstudio ``Cameras``), for records that predate the
                cameras in ``attack.json``; not needed otherwise.
            rebuilt: the poisoned views as the run's loaded pipeline resolved them again (same config,
                same dataset), for records that predate ``views.npz``: their exact float targets are
                used instead of the 8-bit PNGs, so such a run scores as it did before.

        Raises:
            RecordError: no ``attack.json`` (a run trained without the attack), an unreadable one, or a
                poisoned view whose target or mask is missing.
        """
        path = attack_dir / RECORD_FILE
        if not path.is_file():
            raise RecordError(f"no attack record at {path} (a run trained without the attack?)")
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            listed = [(int(v["index"]), str(v["name"]), v) for v in data["poisoned_views"]]
        except (OSError, ValueError, KeyError, TypeError) as err:
            raise RecordError(f"cannot read {path}: {type(err).__name__}: {err}") from None
        images = _ViewImages(attack_dir, {v.index: v for v in rebuilt})
        views = [
            PoisonView(
                index, name, *_camera(entry, index, cameras, path), *images.mask_and_target(index, name)
            )
            for index, name, entry in listed
        ]
        try:
            record = cls.from_json(data, views)
        except TypeError as err:
            raise RecordError(f"cannot read {path}: {err}") from None
        record.support_targets = images.support_targets()
        return record

    @staticmethod
    def exists(attack_dir: Path) -> bool:
        return (attack_dir / RECORD_FILE).is_file()


def write_injection_files(
    attack_dir: Path, means: Tensor, colors: Tensor, grid: DensityGrid, kde: DensityGrid
) -> None:
    """The injection's files: the poison centres with their colours (``poison_points.ply``; ``means``
    ``[M, 3]`` scene units, ``colors`` ``[M, 3]`` RGB in [0, 1]) and the voxel density with its KDE
    (``density_grid.npz``)."""
    import open3d as o3d

    attack_dir.mkdir(parents=True, exist_ok=True)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(means.double().cpu().numpy()))
    cloud.colors = o3d.utility.Vector3dVector(colors.clamp(0, 1).double().cpu().numpy())
    o3d.io.write_point_cloud(str(attack_dir / POISON_POINTS_FILE), cloud)
    grid.save_npz(attack_dir / DENSITY_GRID_FILE, extras={"kde": kde.values})


class _ViewImages:
    """Targets and masks of a record: ``views.npz``; for records that predate it the views the loaded
    pipeline rebuilt, else the 8-bit PNGs."""

    def __init__(self, attack_dir: Path, rebuilt: dict[int, PoisonView]) -> None:
        self.attack_dir = attack_dir
        self.rebuilt = rebuilt
        npz = attack_dir / VIEWS_FILE
        try:
            self.arrays = dict(np.load(npz)) if npz.is_file() else None
        except (OSError, ValueError) as err:
            raise RecordError(f"cannot read {npz}: {type(err).__name__}: {err}") from None

    def support_targets(self) -> dict[int, Tensor]:
        """The support views' training images (train index -> [H, W, 3] float32): ``views.npz``, else
        the 8-bit ``viewNNNN_support.png`` (records written before the injection rewrote ``views.npz``)."""
        arrays = {k: v for k, v in (self.arrays or {}).items() if k.startswith("support_")}
        if arrays:
            images = {int(k.removeprefix("support_")): np.asarray(v, np.float32) for k, v in arrays.items()}
        else:
            pngs = sorted(self.attack_dir.glob("view[0-9][0-9][0-9][0-9]_support.png"))
            images = {int(p.name[4:8]): to_float32(read_image(p))[..., :3] for p in pngs}
        return {index: torch.from_numpy(image) for index, image in images.items()}

    def mask_and_target(self, index: int, name: str) -> tuple[Tensor, Tensor]:
        key = f"{index:04d}"
        if self.arrays is not None and f"target_{key}" in self.arrays and f"mask_{key}" in self.arrays:
            target, mask = self.arrays[f"target_{key}"], self.arrays[f"mask_{key}"]
        elif self.arrays is None and index in self.rebuilt:
            return self.rebuilt[index].mask.cpu(), self.rebuilt[index].target.cpu()
        else:
            try:
                target = to_float32(read_image(self.attack_dir / f"view{key}_target.png"))[..., :3]
                mask = to_float32(read_image(self.attack_dir / f"view{key}_mask.png"))
            except StealthNSError as err:
                raise RecordError(f"missing target/mask of poisoned view {name}: {err}") from None
            mask = (mask if mask.ndim == 2 else mask[..., 0]) > 0.5
        mask, target = np.asarray(mask, dtype=bool), np.asarray(target, dtype=np.float32)
        return torch.from_numpy(mask), torch.from_numpy(target)


def _camera(
    entry: dict[str, Any], index: int, cameras: Any, path: Path
) -> tuple[Tensor, float, float, float, float]:
    """(c2w, fx, fy, cx, cy) of a listed view: from the record, else from the dataset's cameras."""
    if "c2w" in entry:
        c2w = torch.tensor(entry["c2w"], dtype=torch.float32)
        return c2w, float(entry["fx"]), float(entry["fy"]), float(entry["cx"]), float(entry["cy"])
    if cameras is None or not 0 <= index < len(cameras):
        raise RecordError(f"{path} predates the cameras in the record; open it with its run's dataset")
    cam = cameras[index]
    return cam.camera_to_worlds.float(), float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy)
