"""Every attack option is checked when the pipeline is built: one line naming the option, its value
and the allowed range, before any data is loaded (issue 13, items 5 and 6)."""

from __future__ import annotations

import ast
import dataclasses
import inspect
import math
import typing
from pathlib import Path

import pytest
from attack_helpers import build_pipeline

from stealth_ns.attack import config as config_module
from stealth_ns.attack.config import AttackConfig
from stealth_ns.attack.illusion import BUILTIN_ILLUSIONS
from stealth_ns.attack.noise_schedule import NOISE_DECAYS
from stealth_ns.attack.options import (
    STEALTH_NS,
    AttackSettings,
    command_options,
    draws_view_noise,
    option_name,
    option_words,
    spelled_as,
)
from stealth_ns.attack.validation import validate_attack_config
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.scene_generator.writer import write_ply

NAN, INF = math.nan, math.inf

BAD_VALUES: dict[str, list] = {
    "enabled": ["yes", 1],
    "illusion": ["", "   "],
    "illusion_mask": [Path("/no/such/mask.png")],
    "illusion_center": [(1.5, 0.5), (0.5, -0.1), (NAN, 0.5), (0.5,), (0.1, 0.2, 0.3)],
    "illusion_scale": [0.0, -0.4, NAN, INF, 3.0],
    "views": [("",), (-1,)],
    "multi_view": [0, 5, -1, 2.0],
    "support_views": [-1, 9, 1.5, "3"],
    "gt_replacement": ["no"],
    "density_guided": [0],
    "view_noise": [None],
    "voxel_size": [0.0, -0.01, NAN, INF],
    "grid_resolution": [1, 0, -160, 100_000, 160.0],
    "bandwidth": [0.0, -7.5, NAN, INF],
    "outlier_removal": ["true"],
    "placement": ["nearest", ""],
    "visibility_margin": [-0.05, NAN, INF],
    "t_min_fraction": [0.0, -0.075, 1.0, 2.0, NAN],
    "unseen_t_min_fraction": [0.0, -0.01, 1.0, NAN, INF],
    "depth_floor": [-0.1, 1.0, 2.0, NAN, INF],
    "proximity_weight": [-1.0, NAN, INF],
    "proximity_target": [0.0, 1.0, -0.3, NAN],
    "t_min": [0.0, -0.3, NAN, INF],
    "samples_per_ray": [0, -1, 10**9, 1024.5],
    "tie_break": ["last"],
    "injection_step": [-1, -100, 1.5],
    "poison_opacity": [0.0, 1.0, -0.1, 1.5, NAN],
    "poison_scale": [0.0, -0.5, NAN, INF],
    "poisoned_view_repeat": [0, -1, 1.5, "3"],
    "noise_sigma0": [-1.0, NAN, INF],
    "noise_decay": ["exponential"],
    "seed": [-1, 0.5],
}


def test_every_option_has_bad_values():
    """A new AttackConfig field must get a rule in validation.py and an entry here."""
    assert set(BAD_VALUES) == {f.name for f in dataclasses.fields(AttackConfig)}


def test_every_choice_of_a_choice_option_passes():
    """A ``Literal`` option accepts exactly what the code behind it does: ``noise_decay`` every decay
    of the noise schedule (``constant`` included), ``placement`` and ``tie_break`` their choices."""
    hints = typing.get_type_hints(AttackConfig)
    choices = {
        f.name: typing.get_args(hints[f.name])
        for f in dataclasses.fields(AttackConfig)
        if typing.get_origin(hints[f.name]) is typing.Literal
    }
    assert set(choices) == {"placement", "tie_break", "noise_decay"}
    assert choices["noise_decay"] == NOISE_DECAYS and "constant" in NOISE_DECAYS
    for name, values in choices.items():
        for value in values:
            validate_attack_config(dataclasses.replace(AttackConfig(), **{name: value}))


def test_illusion_help_lists_the_builtins():
    """The ``--pipeline.attack.illusion`` help (the field's docstring, as tyro shows it) names every
    built-in illusion."""
    tree = ast.parse(inspect.getsource(config_module))
    body = next(n for n in ast.walk(tree) if isinstance(n, ast.ClassDef) and n.name == "AttackConfig").body
    index = next(
        i
        for i, n in enumerate(body)
        if isinstance(n, ast.AnnAssign) and getattr(n.target, "id", "") == "illusion"
    )
    help_text = body[index + 1].value.value
    assert all(f"``{name}``" in help_text for name in BUILTIN_ILLUSIONS), help_text
    assert "stealth-ns illusions" not in help_text


def test_defaults_and_edge_values_pass():
    validate_attack_config(AttackConfig())
    validate_attack_config(
        AttackConfig(
            t_min=0.05,
            voxel_size=0.01,
            injection_step=None,
            noise_sigma0=0.0,
            visibility_margin=0.0,
            illusion_center=(0.0, 1.0),
            illusion_scale=1.0,
            multi_view=4,
            views=("3", "frame_00004.png"),
            grid_resolution=2,
            samples_per_ray=1,
        )
    )
    validate_attack_config(AttackConfig(injection_step=99), max_iterations=100)


@pytest.mark.parametrize(
    "name,value", [(name, value) for name, values in BAD_VALUES.items() for value in values]
)
def test_bad_value_is_one_line_naming_the_option(name, value):
    with pytest.raises(StealthNSError) as info:
        validate_attack_config(dataclasses.replace(AttackConfig(), **{name: value}))
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(option_name(name) + " must be "), message
    assert f"got {value!r}" in message or f"got {str(value)!r}" in message, message


def test_injection_step_must_come_before_the_last_iteration():
    with pytest.raises(StealthNSError, match=r"injection-step must be .*\[0, 100\).* got 100"):
        validate_attack_config(AttackConfig(injection_step=100), max_iterations=100)


@pytest.mark.parametrize(
    "name,value",
    [
        ("t_min", -0.3),
        ("noise_sigma0", NAN),
        ("poison_opacity", 1.0),
        ("injection_step", -1),
        ("bandwidth", 0.0),
    ],
)
def test_pipeline_refuses_bad_options_before_loading_data(name, value, tmp_path):
    # the dataset does not even exist: the option is refused before nerfstudio reads anything
    with pytest.raises(SystemExit) as exc:
        build_pipeline(tmp_path / "no-such-scene", AttackConfig(**{name: value}))
    message = str(exc.value)
    assert message.startswith(f"stealth-ns: error: {option_name(name)} must be ") and "\n" not in message
    assert repr(value) in message


def test_injection_after_the_last_step_is_refused(tiny_orbit_scene, tmp_path):
    from nerfstudio.engine.callbacks import TrainingCallbackAttributes

    pipeline = build_pipeline(tiny_orbit_scene, AttackConfig(injection_step=None))  # warm-up: step 5
    trainer = type("T", (), {"config": type("C", (), {"max_num_iterations": 5})(), "base_dir": tmp_path})()
    attrs = TrainingCallbackAttributes(optimizers=None, grad_scaler=None, pipeline=pipeline, trainer=trainer)
    with pytest.raises(SystemExit, match=r"injection-step must be None or a step in \[0, 5\).*got 5"):
        pipeline.get_training_callbacks(attrs)


def _scene_copy(src: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(src, dst)
    return dst


@pytest.mark.parametrize("case", ["missing", "empty"])
def test_missing_or_empty_seed_point_file_is_refused(tiny_orbit_scene, tmp_path, case):
    import numpy as np

    scene = _scene_copy(tiny_orbit_scene, tmp_path / "scene")
    if case == "missing":
        (scene / "sparse_pc.ply").unlink()
    else:
        write_ply(scene / "sparse_pc.ply", np.zeros((0, 3)), np.zeros((0, 3), np.uint8))
    with pytest.raises(SystemExit) as exc:
        build_pipeline(scene, AttackConfig())
    message = str(exc.value)
    assert "\n" not in message and "sparse_pc.ply" in message, message
    assert ("does not exist" if case == "missing" else "has no points") in message, message
    assert "stealth-ns seed-points --data" in message


def test_attack_package_loads_without_nerfstudio_and_its_config_without_torch():
    """``stealth_ns.attack`` is pure math and settings: no module of it imports nerfstudio, and the
    config (with the noise schedule whose ``NoiseDecay`` it uses) does not even import torch."""
    import subprocess
    import sys

    code = (
        "import sys, importlib, pkgutil, stealth_ns.attack as a\n"
        "import stealth_ns.attack.config\n"
        "light = sorted(m for m in ('torch', 'nerfstudio') if m in sys.modules)\n"
        "for m in pkgutil.iter_modules(a.__path__): importlib.import_module('stealth_ns.attack.' + m.name)\n"
        "print(light, 'nerfstudio' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[] False"


# ------------------------------------------------------------------ the options on a command line
@dataclasses.dataclass
class _Pipeline:
    attack: AttackConfig = dataclasses.field(default_factory=AttackConfig)


@dataclasses.dataclass
class _NsTrain:
    """Where ns-train puts the attack (``--pipeline.attack.*``), parsed as nerfstudio parses it."""

    pipeline: _Pipeline = dataclasses.field(default_factory=_Pipeline)


def _ns_train_parse(words: tuple[str, ...]) -> AttackConfig:
    import tyro

    return tyro.cli(tyro.conf.FlagConversionOff[_NsTrain], args=list(words)).pipeline.attack


def test_command_options_spell_each_type_as_the_commands_read_it():
    settings = AttackSettings.of(
        enabled=True, bandwidth=7.5, noise_sigma0=100.0, multi_view=2, injection_step=None,
        t_min_fraction=0.1, poison_scale=2.0, views=("a.png", "3"), illusion_center=(0.25, 0.5),
    )  # fmt: skip
    assert command_options(settings) == (
        "--pipeline.attack.enabled", "True", "--pipeline.attack.bandwidth", "7.5",
        "--pipeline.attack.noise-sigma0", "100", "--pipeline.attack.multi-view", "2",
        "--pipeline.attack.injection-step", "None", "--pipeline.attack.t-min-fraction", "0.1",
        "--pipeline.attack.poison-scale", "2", "--pipeline.attack.views", "a.png", "3",
        "--pipeline.attack.illusion-center", "0.25", "0.5",
    )  # fmt: skip
    assert _ns_train_parse(command_options(settings)) == settings.config()
    # stealth-ns commands: no prefix, and a boolean is a flag
    flags = AttackSettings.of(view_noise=True, density_guided=False, noise_sigma0=30.0)
    assert command_options(flags, STEALTH_NS) == (
        "--view-noise",
        "--no-density-guided",
        "--noise-sigma0",
        "30",
    )
    # a float {:g} would round is written whole; a field given twice: both, the later one counts
    assert command_options(AttackSettings.of(bandwidth=1.23456789)) == (
        "--pipeline.attack.bandwidth",
        "1.23456789",
    )
    twice = AttackSettings.of(noise_sigma0=100.0).then(noise_sigma0=30.0)
    assert command_options(twice)[-1] == "30" and twice.config().noise_sigma0 == 30.0
    assert _ns_train_parse(command_options(twice)).noise_sigma0 == 30.0
    with pytest.raises(ValueError, match="not AttackConfig fields: t_max"):
        AttackSettings.of(t_max=1.0)


def test_every_preset_run_parses_back_to_its_settings():
    """ns-train reads each bench run's attack options as the AttackConfig its typed settings make."""
    from stealth_ns.method_configs.attack_experiments import RUNS

    for run in RUNS:
        attack = run.attack.then(views=("frame_00001.png",), seed=3)
        assert _ns_train_parse(command_options(attack)) == attack.config(), run.key


def test_draws_view_noise_reads_the_typed_attack():
    assert draws_view_noise(AttackConfig())
    for off in ({"enabled": False}, {"view_noise": False}, {"noise_sigma0": 0.0}):
        assert not draws_view_noise(AttackConfig(**off)), off


@pytest.mark.parametrize("name,value", [(n, vs[0]) for n, vs in BAD_VALUES.items()])
def test_messages_use_the_spelling_of_the_command(name, value):
    """poison-dataset / ipa-poison take the options as --NAME: their check names them so."""
    with pytest.raises(StealthNSError) as info:
        validate_attack_config(dataclasses.replace(AttackConfig(), **{name: value}), spelling=STEALTH_NS)
    assert str(info.value).startswith(option_name(name, STEALTH_NS) + " must be "), str(info.value)
    assert option_name(name, STEALTH_NS) == "--" + name.replace("_", "-")
    assert "--pipeline.attack." not in str(info.value)
    with pytest.raises(StealthNSError, match=r"^--support-views 2 shows .* needs --density-guided and"):
        validate_attack_config(AttackConfig(support_views=2, density_guided=False), spelling=STEALTH_NS)


def test_messages_inside_a_command_take_its_spelling():
    """The pipeline's own messages (raised once it holds the data) name an option as the command running
    spells it: ns-train's outside, stealth-ns' inside ``spelled_as(STEALTH_NS)`` (poison-dataset,
    ipa-poison), a boolean as the flag that command takes; no text is rewritten."""
    assert option_name("t_min") == "--pipeline.attack.t-min"
    assert option_words("density_guided", False) == "--pipeline.attack.density-guided False"
    with spelled_as(STEALTH_NS):
        assert option_name("t_min") == "--t-min"
        assert option_words("density_guided", False) == "--no-density-guided"
        assert option_words("support_views", 2) == "--support-views 2"
        with pytest.raises(StealthNSError, match=r"^--support-views 2 shows .* needs --density-guided and"):
            validate_attack_config(AttackConfig(support_views=2, density_guided=False))
    assert option_name("t_min") == "--pipeline.attack.t-min"
    with pytest.raises(StealthNSError, match=r"^--pipeline.attack.support-views 2 .* needs --pipeline"):
        validate_attack_config(AttackConfig(support_views=2, density_guided=False))
