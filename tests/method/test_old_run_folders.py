"""Run folders trained before the modules moved into packages still load: their ``config.yml`` names
classes by the old module paths (``stealth_ns.pipeline.StealthPipelineConfig``), which
:mod:`stealth_ns.foundation.moved_modules` maps to today's, for the safe loader and for nerfstudio's own
YAML loader (``ns-eval``, ``ns-viewer``)."""

from __future__ import annotations

import importlib

import pytest
import yaml

from stealth_ns.foundation.moved_modules import MOVED, current_name
from stealth_ns.method.optimizers import FusedAdam, FusedAdamOptimizerConfig
from stealth_ns.method.pipeline import StealthPipeline, StealthPipelineConfig
from stealth_ns.method.safe_config import SafeConfigLoader, UnsafeConfigError

OLD_CONFIG = """\
optimizer: !!python/object:stealth_ns.optimizers.FusedAdamOptimizerConfig
  _target: !!python/name:stealth_ns.optimizers.FusedAdam ''
  lr: 0.25
  eps: 1.0e-15
  fused: true
pipeline: !!python/name:stealth_ns.pipeline.StealthPipeline ''
"""


def test_old_paths_name_todays_modules():
    assert current_name("stealth_ns.pipeline.StealthPipelineConfig") == (
        "stealth_ns.method.pipeline.StealthPipelineConfig"
    )
    assert current_name("stealth_ns.pipelines.X") == "stealth_ns.pipelines.X"  # a prefix is not a module
    assert current_name("nerfstudio.models.splatfacto") == "nerfstudio.models.splatfacto"
    for old, new in MOVED.items():
        assert importlib.import_module(old) is importlib.import_module(new)


@pytest.mark.parametrize("loader", [SafeConfigLoader, yaml.Loader], ids=["safe", "nerfstudio"])
def test_a_config_with_the_old_paths_loads(loader):
    config = yaml.load(OLD_CONFIG, Loader=loader)
    assert type(config["optimizer"]) is FusedAdamOptimizerConfig
    assert config["optimizer"]._target is FusedAdam and config["optimizer"].lr == 0.25
    assert config["pipeline"] is StealthPipeline
    assert StealthPipelineConfig.__module__ == "stealth_ns.method.pipeline"


def test_the_safe_loader_still_refuses_what_no_config_holds():
    """The old paths open no door: a module that was never moved is judged by its own name."""
    with pytest.raises(UnsafeConfigError):
        yaml.load("!!python/name:stealth_ns.cli.main ''", Loader=SafeConfigLoader)
    with pytest.raises(UnsafeConfigError):
        yaml.load("!!python/object/apply:os.system ['true']", Loader=SafeConfigLoader)
