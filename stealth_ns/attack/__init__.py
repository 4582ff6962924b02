"""Pure-function math and assets of the StealthAttack poisoning method (paper section 3).

Modules (no nerfstudio imports; numpy / scipy / scikit-image / torch only):

* :mod:`stealth_ns.attack.density` -- voxel density grid of a point cloud and its Gaussian KDE
  (paper section 3.3, "Scene Space Analysis" and "Continuous Density Estimation").
* :mod:`stealth_ns.attack.ray_search` -- pixel rays of the poisoned view and the minimum-density
  point along each ray (paper eq. 4, "Optimal Position Selection").
* :mod:`stealth_ns.attack.noise_schedule` -- decaying Gaussian noise on innocent views (section 3.4).
* :mod:`stealth_ns.attack.illusion` -- illusory objects: built-in cut-outs, loading, placement and
  compositing onto the poisoned training image.
* :mod:`stealth_ns.attack.views` -- choice of the poisoned view(s) from the training cameras.
"""
