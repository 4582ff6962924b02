"""The attack's configuration: everything a user sets, in one place (``--pipeline.attack.*``).

Defaults come from the paper (StealthAttack, ICCV 2025, §3-4) and, where the paper is
silent, from the authors' code (see ``docs/design/attack.md``).

Units: the defaults are scale-free -- ``t_min_fraction`` is a fraction of the poisoned view's
scene depth, ``grid_resolution`` / ``bandwidth`` count voxels, ``poison_scale`` counts pixel
footprints -- so they transfer between captures. The absolute overrides (``t_min``,
``voxel_size``) are in nerfstudio's rescaled scene units (cameras recentred and scaled into
[-1, 1]³ by ``auto_scale_poses``).

A plain dataclass (tyro builds ``--pipeline.attack.*`` from it; a run's ``config.yml`` stores it
as ``!!python/object:stealth_ns.attack.config.AttackConfig``): importing this module loads neither
nerfstudio nor torch, so the CLI's tools (``stealth-ns rank-views``) can read the defaults.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from stealth_ns.attack.noise_schedule import NoiseDecay


@dataclass
class AttackConfig:
    """StealthAttack settings (illusion, poisoned views, components, KDE, injection, noise)."""

    enabled: bool = True
    """False trains the same pipeline without any attack (the clean baseline)."""

    # --- the illusion --------------------------------------------------------------------
    illusion: str = "astronaut"
    """A built-in object (``astronaut``, ``horse``, ``coffee``, ``logo`` or ``coin``: cut-outs of images
    shipped with scikit-image, ``stealth_ns.attack.illusion.BUILTIN_ILLUSIONS``) or the path of an RGBA
    image (alpha = mask) or of an RGB image used with ``illusion_mask``."""
    illusion_mask: Path | None = None
    """Mask image for an RGB illusion (pixels > 0.5 after normalising are the object)."""
    illusion_center: tuple[float, float] = (0.5, 0.5)
    """Where the illusion's centre sits in the poisoned view, as fractions of (width, height)."""
    illusion_scale: float = 0.4
    """Illusion height as a fraction of the poisoned view's height (aspect kept)."""

    # --- poisoned views ------------------------------------------------------------------
    views: tuple[str, ...] = ()
    """Poisoned training views by index or image name; empty = the median training frame."""
    multi_view: int = 1
    """1..4 poisoned views at 0°, 90°, 180°, 270° about the scene's up axis from the first
    poisoned view (the paper's multi-view attack); each the nearest training view."""

    # --- components (the paper's Table 6 ablation) -----------------------------------------
    gt_replacement: bool = True
    """Replace the poisoned view's training image with the illusion composite I_ILL."""
    density_guided: bool = True
    """Inject one poison Gaussian per illusion pixel at the minimum-density point of its ray."""
    view_noise: bool = True
    """View-consistency disruption: Gaussian noise with a decaying sigma on innocent views."""

    support_views: int = 0
    """K training views nearest each poisoned view show the illusion too (0 = the paper's attack): a
    stealth-aware variant (``stealth_ns.attack.support``, ``docs/design/stealth.md``). Their images become
    renders of the poison over their own, and the poison goes where they see it, so its support
    spreads over K + 1 views. Needs the density-guided component and GT replacement."""

    # --- density and KDE (§3.3) --------------------------------------------------------------
    voxel_size: float | None = None
    """Voxel edge in scene units; None = the AABB's longest side / ``grid_resolution``."""
    grid_resolution: int = 160
    """Voxels along the longest AABB side when ``voxel_size`` is None."""
    bandwidth: float = 7.5
    """KDE bandwidth h in voxels (paper's default 7.5; its ablation varies 0.1..10)."""
    outlier_removal: bool = True
    """Statistical outlier removal (20 neighbours, 2 std) before the AABB, as the authors did."""
    placement: Literal["view-aware", "kde", "surface"] = "view-aware"
    """Where on its illusion ray a poison Gaussian goes. ``kde``: the paper's arg-min of the KDE
    density (eq. 4) from ``t_min_fraction`` on. ``view-aware``: the sample seen by the fewest
    innocent training cameras (inside their image and not behind the surface their render
    shows), the KDE density breaking ties; a part of the ray no innocent camera sees is searched
    from the nearer of ``t_min_fraction`` and ``unseen_t_min_fraction`` on. The paper's "low
    density = weakly constrained" made explicit. Measured (``docs/design/attack.md``, 3000 lite
    iterations): ``kde`` keeps 0 of 815 poison Gaussians on the forward-facing ``facing`` scene
    (9.75 dB); ``view-aware`` succeeds on ``orbit`` (30.01 dB), ``facing`` (44.95), the real
    ``fox`` capture (38.66) and ``forward``'s Easy and Median views (36.56, 27.35); its Hard
    view fails (8.22).

    ``surface`` (a stealth-aware variant, ``docs/design/stealth.md``): on the surface the pixel shows,
    seen by every innocent camera that sees that surface, the illusion carried by view-dependent
    colour (SH) alone."""
    visibility_margin: float = 0.05
    """``view-aware``: a point up to this fraction of the rendered depth behind a camera's surface
    still counts as seen by that camera."""
    t_min_fraction: float = 0.01
    """Nearest distance along a ray where a poison Gaussian may go, as a fraction of the poisoned
    view's median rendered depth (scale-free), and never nearer than two rasterizer near planes
    (where it would no longer be drawn). Measured, view-aware: 0.01 succeeds on every scene
    (orbit 30.01 dB, forward Median 27.35, facing 44.95, fox 38.66); 0.075 (the orbit-tuned value
    before) gives orbit 31.33 dB but fails on forward Median (10.06) and, without the unseen
    bound below, on facing (10.11)."""
    unseen_t_min_fraction: float = 0.01
    """``view-aware``: the nearest distance (fraction of the median rendered depth) for a poison
    Gaussian that no innocent camera sees, when ``t_min_fraction`` is larger: such poison may
    come nearer than seen poison. On forward-facing captures the only unseen place is the
    stretch just in front of the poisoned camera, before the other frusta overlap (facing with
    ``t_min_fraction`` 0.075: 10.11 dB without it, 44.95 dB with it)."""
    depth_floor: float = 0.0
    """An adaptive variant against camera-proximity (docs/design/stealth.md, "Adaptive attacks"): no poison
    Gaussian is placed nearer a training camera that has it in its image than this share of that
    camera's median rendered scene depth -- camera-proximity's own measure, which ``defend`` cuts at
    0.15 and ``scan`` flags below 0.3. An illusion ray without such a sample gets no poison Gaussian.
    0 = off (the paper's attack)."""
    proximity_weight: float = 0.0
    """A white-box adaptive variant (docs/design/stealth.md, "Adaptive attacks"): weight of a training loss on
    the poison Gaussians from the injection on -- how far each one's camera-proximity ratio lies below
    ``proximity_target``, relative to it, averaged over up to 8192 of them drawn each step
    (:mod:`stealth_ns.attack.proximity_term`). It trains the poison out of the defence's reach while
    the photometric loss keeps the illusion. 0 = off (the paper's attack)."""
    proximity_target: float = 0.3
    """The ratio ``proximity_weight`` pushes the poison to: the scan's flag line (0.3), twice defend's
    cut (0.15)."""
    t_min: float | None = None
    """Absolute near distance in nerfstudio's rescaled scene units; overrides ``t_min_fraction``
    (the paper's 0.3 is in Mip-NeRF 360's COLMAP units, ~4x ours)."""
    samples_per_ray: int = 1024
    """Samples between t_min and the rendered depth (the authors: 8192, nearest voxel)."""
    tie_break: Literal["nearest-surface", "first", "middle"] = "nearest-surface"
    """Among equally good samples: nearest the surface (default), nearest the camera (the
    authors' argmin), or the middle of the first minimal run."""

    # --- injection ---------------------------------------------------------------------------
    injection_step: int | None = 0
    """Training step of the injection: 0 = into the seed points before training, as the authors'
    code did; None = at the end of the model's warm-up (after the initial reconstruction, as the
    paper describes). Measured on the orbit scene (t_min 0.07): step 0 -> V-illusory 32.4 dB,
    end of warm-up (step 150) -> 20.8 dB; the poison must grow with the scene while the
    view-consistency noise is strongest."""
    poison_opacity: float = 0.1
    """Initial opacity of poison Gaussians (splatfacto's initial opacity)."""
    poison_scale: float = 0.5
    """Poison Gaussian std-dev in pixel footprints at its depth (depth / focal length)."""
    poisoned_view_repeat: int = 1
    """Times each view that shows the illusion (the poisoned views, and support views from the
    injection on) is drawn per pass over the training views; 1 = once, like every view (the paper's
    attack). A schedule knob of the in-loop attacker: on a capture of 67-184 photos a lite run shows
    the poisoned view only 19-45 times (docs/design/captures.md)."""

    # --- view-consistency noise (§3.4) ---------------------------------------------------------
    noise_sigma0: float = 100.0
    """Initial noise std-dev on the 0-255 scale (paper: 30 or 100; 100 is the default)."""
    noise_decay: NoiseDecay = "linear"
    """How sigma decays to 0 over the training run (paper eqs. 6-8: linear, cosine, sqrt), or
    ``constant``: sigma stays at ``noise_sigma0`` (an ablation: noise that never fades)."""
    seed: int = 0
    """Seed of the noise (deterministic per seed, view and step)."""
