"""``stealth-ns bench attack``: the paper's Tables 1-6 on generated scenes and dataset folders.

The presets (:mod:`stealth_ns.method_configs.attack_experiments`) say which runs each table
shows. This package resolves ``--scenes`` (generated presets, and dataset folders ``NAME=PATH``
in nerfstudio-data, COLMAP or Blender format, used in place), plans the runs of the chosen
tables and scenes (a run shared by several tables is trained once), generates the presets and
triangulates the seed points of folders without them (:mod:`stealth_ns.datasets.seed_points`, into a
seeded copy under ``OUTPUT/scenes``), trains what is missing with a progress bar across runs
(each ``ns-train``'s output goes to ``ns-train.log`` in its run folder; one after another, or
as Ray tasks on a cluster with ``--executor ray``: :mod:`stealth_ns.bench.executors`), reuses
finished runs and retrains interrupted ones (see :mod:`stealth_ns.runs.training`), compares every poisoned
run with the clean run of its scene (:func:`stealth_ns.report.numbers.compare_runs`, cached
as ``metrics.json`` in the poisoned run's folder) and writes ``OUTPUT/tables.md`` (markdown
shaped like the paper's tables) and ``OUTPUT/results.json`` (every number, the scenes'
sources, the environment, timings).

Layout under ``OUTPUT``: ``scenes/PRESET-seedS`` (generated once), ``scenes/NAME`` and
``scenes/NAME.seed-points.json`` (a folder's seeded copy and its record, made once),
``scenes/*.views.json`` (the KDE views), ``runs/SCENE-seedS-ITERSit/METHOD/RUN`` (one nerfstudio
run each), ``tables.md``, ``results.json``. Both outputs are rewritten after every run, so they
fill in while the benchmark runs (``"complete": false`` until the end).

The modules, in the order a benchmark uses them: :mod:`~stealth_ns.bench.scenes` (``--scenes`` and
the KDE views), :mod:`~stealth_ns.bench.plan` (the runs of the chosen tables, deduplicated),
:mod:`~stealth_ns.bench.poisoned_copies` (the data-only and IPA-Splat rows' poisoned datasets),
:mod:`~stealth_ns.bench.executors` (local or Ray), :mod:`~stealth_ns.bench.execute` (train, compare,
cache the metrics), :mod:`~stealth_ns.bench.results` and :mod:`~stealth_ns.bench.tables` (results.json
and tables.md), :mod:`~stealth_ns.bench.defence_table` (Table D) and :mod:`~stealth_ns.bench.attack`
(the command). ``stealth-ns bench train`` is :mod:`~stealth_ns.bench.train_step`.
"""
