"""The training runs of ``stealth-ns bench attack``: one :class:`RunSpec` per (scene, name), by the scene's
kind (:func:`scene_runs`). A run that several tables show is defined once, and every attack run spells
out all the settings the tables vary, so a run never depends on the attack's defaults."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from stealth_ns.attack.noise_schedule import NoiseDecay
from stealth_ns.attack.options import AttackSettings
from stealth_ns.method_configs.experiment_scenes import SCENES, scene_kind
from stealth_ns.method_configs.stealth_settings import STEALTH_SETTINGS

#: How a run picks its poisoned view: the median-indexed training frame (the attack's default,
#: the paper's choice for uniform captures) or a level of the KDE difficulty protocol.
ViewChoice = Literal["median-index", "easy", "median", "hard"]
#: The KDE protocol's levels, as run names and view choices of a ``kde`` scene.
KDE_LEVELS: tuple[ViewChoice, ...] = ("easy", "median", "hard")
#: The attacks a table row shows (``bench attack --attacks``): in the training loop, dataset attacks.
ATTACKS: tuple[str, ...] = ("in-loop", "data-only", "ipa")


@dataclass(frozen=True)
class RunSpec:
    """One training run of a scene: its name (the run folder) and its attack settings."""

    scene: str
    """A scene: a preset or a dataset folder's name (``--scenes NAME=PATH``)."""
    name: str
    """Run name, unique per scene: the run folder's name."""
    attack: AttackSettings = AttackSettings()
    """The attack's settings (ns-train's ``--pipeline.attack.*``), without the view selection."""
    view: ViewChoice = "median-index"
    """The poisoned view (the base view of a multi-view attack)."""
    clean: bool = False
    """The clean baseline (attack disabled) that every poisoned run of the scene is compared with."""
    label: str = ""
    """A short description for listings."""
    poisoning: Literal["", "data-only", "ipa"] = ""
    """A dataset attack: the run is a plain victim (:attr:`attack` turns the attack off) trained on a
    poisoned copy of the scene made by ``stealth-ns poison-dataset`` (data-only) or ``ipa-poison``
    (IPA-Splat)."""
    poison_attack: AttackSettings = AttackSettings()
    """More attack settings of that command (the view comes from :attr:`view`)."""

    @property
    def key(self) -> str:
        """``scene/name``, the run's identifier in plans and results."""
        return f"{self.scene}/{self.name}"


def attack_settings(
    gt_replacement: bool = True,
    density_guided: bool = True,
    view_noise: bool = True,
    bandwidth: float = 7.5,
    noise_sigma0: float = 100.0,
    noise_decay: NoiseDecay = "linear",
    multi_view: int = 1,
) -> AttackSettings:
    """The attack settings of an attack run, every setting the tables vary given (in this order).

    Defaults are the paper's method: all three components, h = 7.5, sigma0 = 100, linear decay.
    """
    return AttackSettings.of(
        enabled=True,
        gt_replacement=gt_replacement,
        density_guided=density_guided,
        view_noise=view_noise,
        bandwidth=bandwidth,
        noise_sigma0=noise_sigma0,
        noise_decay=noise_decay,
        multi_view=multi_view,
    )


#: The attack settings of a clean run, and of a dataset attack's plain victim: the attack off.
CLEAN: AttackSettings = AttackSettings.of(enabled=False)
DATA_ONLY_LABEL = "data-only StealthAttack (poisoned dataset: I_ILL + poison seed points; plain victim)"
IPA_LABEL = "IPA-Splat (poisoned dataset; plain victim)"

BANDWIDTHS: tuple[float, ...] = (0.1, 2.5, 5.0, 7.5, 10.0)
NOISE_SIGMA0S: tuple[float, ...] = (30.0, 100.0)
#: Table 5's decay rows: (the attack's noise_decay, the paper's label); the schedule's
#: ``constant`` (an ablation outside the paper's table) is not one of them.
NOISE_DECAY_ROWS: tuple[tuple[NoiseDecay, str], ...] = (
    ("linear", "Linear"),
    ("cosine", "Cosine"),
    ("sqrt", "Square root"),
)
MULTI_VIEWS: tuple[int, ...] = (2, 3, 4)


def bandwidth_run(h: float) -> str:
    return "full" if h == 7.5 else f"h-{h:g}"


def noise_run(sigma0: float, decay: str) -> str:
    return "full" if (sigma0, decay) == (100.0, "linear") else f"sigma{sigma0:g}-{decay}"


def _uniform_runs(scene: str) -> list[RunSpec]:
    """A uniform capture (orbit): the median-indexed view, every ablation of Tables 1, 3-6."""
    runs: list[RunSpec] = [
        RunSpec(scene, "clean", CLEAN, clean=True, label="clean (no attack)"),
        RunSpec(scene, "full", attack_settings(), label="all three components (the paper's method)"),
        RunSpec(scene, "gt-only", attack_settings(density_guided=False, view_noise=False), label="GT only"),
        RunSpec(scene, "gt-density", attack_settings(view_noise=False), label="GT + density-guided"),
        RunSpec(scene, "gt-noise", attack_settings(density_guided=False), label="GT + view noise"),
    ]
    runs += [
        RunSpec(scene, "data-only", CLEAN, poisoning="data-only", label=DATA_ONLY_LABEL),
        RunSpec(scene, "ipa", CLEAN, poisoning="ipa", label=IPA_LABEL),
    ]
    runs += _multi_view_runs(scene, "median-index")
    runs += [
        RunSpec(scene, bandwidth_run(h), attack_settings(bandwidth=h), label=f"bandwidth h={h:g}")
        for h in BANDWIDTHS
        if bandwidth_run(h) != "full"
    ]
    runs += [
        RunSpec(
            scene,
            noise_run(s, d),
            attack_settings(noise_sigma0=s, noise_decay=d),
            label=f"noise sigma0={s:g}, {d} decay",
        )
        for s in NOISE_SIGMA0S
        for d, _ in NOISE_DECAY_ROWS
        if noise_run(s, d) != "full"
    ]
    return runs


def _kde_runs(scene: str) -> list[RunSpec]:
    """A KDE scene (free trajectory, forward-facing, real capture): Easy / Median / Hard views."""
    runs = [RunSpec(scene, "clean", CLEAN, clean=True, label="clean (no attack)")]
    runs += [
        RunSpec(scene, level, attack_settings(), view=level, label=f"{level.capitalize()} view (KDE)")
        for level in KDE_LEVELS
    ]
    runs += [
        RunSpec(scene, f"ipa-{level}", CLEAN, view=level, poisoning="ipa", label=f"{IPA_LABEL}, {level}")
        for level in KDE_LEVELS
    ]
    runs.append(
        RunSpec(scene, "data-only-median", CLEAN, view="median", poisoning="data-only", label=DATA_ONLY_LABEL)
    )
    runs += _multi_view_runs(scene, "median")
    return runs


def _multi_view_runs(scene: str, view: ViewChoice) -> list[RunSpec]:
    """Table 3's runs: 2-4 poisoned views around ``view``, in-loop and IPA-Splat."""
    runs = [
        RunSpec(scene, f"views-{k}", attack_settings(multi_view=k), view=view, label=f"{k} poisoned views")
        for k in MULTI_VIEWS
    ]
    return runs + [
        RunSpec(
            scene,
            f"ipa-views-{k}",
            CLEAN,
            view=view,
            poisoning="ipa",
            poison_attack=AttackSettings.of(multi_view=k),
            label=f"{IPA_LABEL}, {k} backdoor views",
        )
        for k in MULTI_VIEWS
    ]


_KIND_RUNS = {"uniform": _uniform_runs, "kde": _kde_runs}

#: Stealth settings that are another table's run: (on every scene, on uniform scenes only).
_SHARED_EVERYWHERE: dict[str, str] = {"st-views-2": "views-2"}
_SHARED_UNIFORM: dict[str, str] = {"st-sigma-30": noise_run(30.0, "linear")}


def shared_run(scene: str, setting: str) -> str | None:
    """The run of Table 3 or 5 that a stealth ``setting`` is on ``scene``, or None (its own run)."""
    shared = _SHARED_EVERYWHERE | (_SHARED_UNIFORM if scene_kind(scene) == "uniform" else {})
    return shared.get(setting)


def _stealth_runs(scene: str) -> list[RunSpec]:
    """Table 7's runs of a scene (those it shares with Tables 3 and 5 excepted)."""
    view: ViewChoice = "median-index" if scene_kind(scene) == "uniform" else "median"
    return [
        RunSpec(scene, name, attack_settings() + extra, view=view, label=label)
        for name, extra, label in STEALTH_SETTINGS
        if shared_run(scene, name) is None
    ]


def scene_runs(scene: str) -> tuple[RunSpec, ...]:
    """Every run of ``scene`` (declared or a dataset folder), by its kind; the clean baseline first."""
    return tuple(_KIND_RUNS[scene_kind(scene)](scene) + _stealth_runs(scene))


def stealth_run(scene: str, setting: str) -> str:
    """Table 7's run of ``scene`` for ``setting`` (a :data:`STEALTH_SETTINGS` name, or ``default``)."""
    if setting == "default":
        return single_view_run(scene)
    return shared_run(scene, setting) or setting


#: Every run of the declared scenes, clean baselines first within each scene.
RUNS: tuple[RunSpec, ...] = tuple(run for scene in SCENES for run in scene_runs(scene))


def get_run(scene: str, name: str) -> RunSpec:
    """The run ``name`` of ``scene`` (KeyError if none)."""
    for run in scene_runs(scene):
        if run.name == name:
            return run
    raise KeyError(f"{scene}/{name}")


def clean_run(scene: str) -> RunSpec:
    """The clean baseline of ``scene``."""
    (run,) = (r for r in scene_runs(scene) if r.clean)
    return run


def single_view_run(scene: str, attack: Literal["in-loop", "data-only", "ipa"] = "in-loop") -> str:
    """Table 1's run of a scene for an attack: the median-indexed view (uniform) or the KDE Median view."""
    uniform = scene_kind(scene) == "uniform"
    if attack == "data-only":
        return "data-only" if uniform else "data-only-median"
    if attack == "ipa":
        return "ipa" if uniform else "ipa-median"
    return "full" if uniform else "median"
