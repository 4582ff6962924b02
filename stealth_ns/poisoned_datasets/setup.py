"""A stealth-ns pipeline on a user's dataset, outside ``ns-train``: the attacker's view of the data.

Both dataset attacks need what training sets up -- the dataset as nerfstudio normalises it, the
illusion targets of the poisoned views, a model initialised from the seed points -- without the
victim's training loop. :func:`trainer_config` builds the ``TrainerConfig`` ``ns-train METHOD
nerfstudio-data|colmap --data DATA`` would; :func:`setup_pipeline` sets up its pipeline only.
The commands that run them take the attack's options as ``--NAME`` and run inside
``spelled_as(STEALTH_NS)`` (:mod:`stealth_ns.attack.options`), so the pipeline's errors name them so.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import torch

from stealth_ns.attack.config import AttackConfig
from stealth_ns.foundation.errors import StealthNSExit
from stealth_ns.poisoned_datasets.dataset_copy import SourceDataset


def trainer_config(
    source: SourceDataset, attack: AttackConfig, method: str = "stealth-splat-lite", seed: int = 0
) -> Any:
    """The ``TrainerConfig`` of ``METHOD`` on ``source`` with ``attack`` (``--vis tensorboard``); a
    Blender scene gets the blender-data parser and a white background, as NeRF-synthetic is trained."""
    from nerfstudio.data.dataparsers.blender_dataparser import BlenderDataParserConfig
    from nerfstudio.data.dataparsers.colmap_dataparser import ColmapDataParserConfig

    from stealth_ns.method_configs.registry import method_config

    config = copy.deepcopy(method_config(method))
    datamanager = config.pipeline.datamanager
    if source.scene.format == "colmap":
        datamanager.dataparser = ColmapDataParserConfig(
            colmap_path=Path(str(source.colmap_path)), downscale_factor=1, load_3D_points=True
        )
    elif source.scene.format == "blender":
        datamanager.dataparser = BlenderDataParserConfig()
        config.pipeline.model.background_color = "white"
    datamanager.dataparser.data = source.root
    datamanager.data = source.root
    config.pipeline.attack = attack
    config.machine.seed = seed
    config.vis = "tensorboard"
    return config


def device() -> str:
    """Where the attacker computes: the GPU when there is one (gsplat), else the CPU backend."""
    return "cuda" if torch.cuda.is_available() else "cpu"


def setup_pipeline(config: Any, test_mode: str = "val") -> Any:
    """The config's pipeline, set up for training (data loaded, poisoned views resolved) but not trained
    (``test_mode`` "test" loads the held-out split as evaluation does); the pipeline's own one-line errors
    come out as :class:`StealthNSError`."""
    from nerfstudio.scripts.train import _set_random_seed

    _set_random_seed(config.machine.seed)  # as ns-train seeds before the trainer is set up
    try:
        return config.pipeline.setup(device=device(), test_mode=test_mode, world_size=1, local_rank=0)
    except StealthNSExit as err:
        raise err.error from None


def setup_trainer(config: Any) -> Any:
    """nerfstudio's Trainer for ``config``, seeded and set up as ``ns-train`` does (its config.yml
    saved); the pipeline's one-line errors come out as :class:`StealthNSError`."""
    from nerfstudio.scripts.train import _set_random_seed

    _set_random_seed(config.machine.seed)
    try:
        config.save_config()
        trainer = config.setup(local_rank=0, world_size=1)
        trainer.setup()
    except StealthNSExit as err:
        raise err.error from None
    return trainer
