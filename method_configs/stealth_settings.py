"""Settings of ``bench attack``'s stealth tables (7-9): the attack variants beyond the paper's runs.

Each entry is (run name, settings given after the default attack's, label); the runs and tables are
made in :mod:`stealth_ns.method_configs.attack_experiments`.
"""

from __future__ import annotations

from stealth_ns.attack.options import AttackSettings

#: Table 7's rows beyond the default attack: the stealth-aware variants, then the attack's other
#: knobs one at a time (``docs/design/stealth.md``): (run name, settings given after the default attack's,
#: label). A scene shows Table 3's (and a uniform scene Table 5's) runs for the settings they share
#: (``attack_experiments.shared_run``).
STEALTH_SETTINGS: tuple[tuple[str, AttackSettings, str], ...] = (
    ("st-support-3", AttackSettings.of(support_views=3), "support views 3 (stealth-aware)"),
    ("st-support-4", AttackSettings.of(support_views=4), "support views 4 (stealth-aware)"),
    ("st-support-5", AttackSettings.of(support_views=5), "support views 5 (stealth-aware)"),
    ("st-support-6", AttackSettings.of(support_views=6), "support views 6 (stealth-aware)"),
    ("st-surface", AttackSettings.of(placement="surface"), "placement surface (stealth-aware)"),
    ("st-tmin-0.1", AttackSettings.of(t_min_fraction=0.1), "t-min fraction 0.1 (default 0.01)"),
    ("st-scale-2", AttackSettings.of(poison_scale=2.0), "poison scale 2 px (default 0.5)"),
    ("st-opacity-0.5", AttackSettings.of(poison_opacity=0.5), "poison opacity 0.5 (default 0.1)"),
    (
        "st-repeat-3",
        AttackSettings.of(poisoned_view_repeat=3),
        "poisoned view drawn 3 times a pass (default 1)",
    ),
    (
        "st-inject-warmup",
        AttackSettings.of(injection_step=None),
        "injection at the end of warm-up (default 0)",
    ),
    ("st-sigma-30", AttackSettings.of(noise_sigma0=30.0), "noise sigma0 30 (default 100)"),
    ("st-views-2", AttackSettings.of(multi_view=2), "2 poisoned views (default 1)"),
    ("ad-floor-0.15", AttackSettings.of(depth_floor=0.15), "depth floor 0.15 (adaptive)"),
    ("ad-floor-0.3", AttackSettings.of(depth_floor=0.3), "depth floor 0.3 (adaptive)"),
    (
        "ad-floor-0.3-support-3",
        AttackSettings.of(depth_floor=0.3, support_views=3),
        "depth floor 0.3 + support views 3 (adaptive)",
    ),
    (
        "ad-floor-0.35-support-3",
        AttackSettings.of(depth_floor=0.35, support_views=3),
        "depth floor 0.35 + support views 3 (adaptive)",
    ),
    (
        "ad-floor-0.45-support-3",
        AttackSettings.of(depth_floor=0.45, support_views=3),
        "depth floor 0.45 + support views 3 (adaptive)",
    ),
    (
        "ad-floor-0.6-support-3",
        AttackSettings.of(depth_floor=0.6, support_views=3),
        "depth floor 0.6 + support views 3 (adaptive)",
    ),
    ("ad-whitebox", AttackSettings.of(proximity_weight=1.0), "white-box proximity term (adaptive)"),
    (
        "ad-whitebox-support-3",
        AttackSettings.of(proximity_weight=1.0, support_views=3),
        "white-box proximity term + support views 3 (adaptive)",
    ),
)
#: Table 9's settings: adaptive attacks, aimed at camera-proximity and the scan as they are (issue 60);
#: the deeper floors at the scan's scene-level near line (docs/design/scan.md).
ADAPTIVE_VARIANTS: tuple[str, ...] = (
    "ad-floor-0.15",
    "ad-floor-0.3",
    "ad-floor-0.3-support-3",
    "ad-floor-0.35-support-3",
    "ad-floor-0.45-support-3",
    "ad-floor-0.6-support-3",
    "ad-whitebox",
    "ad-whitebox-support-3",
)
#: Table 7's settings, the stealth-aware variants; Table 8 has the others but the adaptive ones.
STEALTH_VARIANTS: tuple[str, ...] = (
    "st-support-3",
    "st-support-4",
    "st-support-5",
    "st-support-6",
    "st-surface",
)
