"""Pure-function math, assets and settings of the StealthAttack poisoning method (paper section 3).

Modules (no nerfstudio imports; numpy / scipy / scikit-image / torch only; ``config`` and
``noise_schedule`` load without torch; ``tests/attack/test_attack_options.py`` checks both):

* :mod:`stealth_ns.attack.config` -- :class:`~stealth_ns.attack.config.AttackConfig`, every option
  (``--pipeline.attack.*``), a plain dataclass; :mod:`stealth_ns.attack.validation` checks them;
  :mod:`stealth_ns.attack.options` writes typed settings as a command's options.
* :mod:`stealth_ns.attack.density` -- voxel density grid of a point cloud and its Gaussian KDE
  (paper section 3.3, "Scene Space Analysis" and "Continuous Density Estimation").
* :mod:`stealth_ns.attack.ray_search` -- pixel rays of the poisoned view and the minimum-density
  point along each ray (paper eq. 4, "Optimal Position Selection").
* :mod:`stealth_ns.attack.visibility` and :mod:`stealth_ns.attack.injection` -- where on its ray
  each poison Gaussian goes, and the poison itself.
* :mod:`stealth_ns.attack.noise_schedule` -- decaying Gaussian noise on innocent views (section 3.4).
* :mod:`stealth_ns.attack.illusion` -- illusory objects: built-in cut-outs, loading, placement and
  compositing onto the poisoned training image.
* :mod:`stealth_ns.attack.views` -- choice of the poisoned view(s) from the training cameras.
* :mod:`stealth_ns.attack.record` -- what a run stores of its attack (``attack/`` in the run folder).
"""
