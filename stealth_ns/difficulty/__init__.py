"""The paper's KDE difficulty protocol: rank training views by the scene density inside their frustum.

StealthAttack §Evaluation Protocol, for scenes with irregular camera trajectories:

1. compute the scene's density distribution with a KDE;
2. compute each camera's density inside its field of view, with a sampling radius of 10 % (of the scene
   diagonal, per the authors' notes);
3. sort the cameras by density and pick three: **Easy** = minimum density (the least covered view, where an
   illusion has the most empty space to live in), **Median** = median density, **Hard** = maximum density.

Our reading, implemented here:

* the scene density is the attack's own KDE (:mod:`stealth_ns.attack.density`) of the dataset's seed point
  cloud (SfM points), every point with weight 1, after the same statistical outlier removal the attack
  applies, on a grid of ``grid_resolution`` voxels along the longest side of the points' bounding box,
  smoothed with a Gaussian of ``bandwidth`` voxels and normalised to a maximum of 1 (the
  :class:`~stealth_ns.attack.config.AttackConfig` defaults, read from it);
* the sampling radius is ``r = radius_fraction * diagonal`` of that (inlier) bounding box;
* a camera's density is the *volume average* of the KDE over the part of its pinhole view frustum that lies
  within distance ``r`` of the camera centre (a cone capped by a sphere). It is estimated with a fixed,
  deterministic quadrature: a regular grid of pixel directions over the image, weighted by the solid angle
  each covers, times depths at the mid-volume of equal-volume shells in ``(0, r]``; KDE values outside the
  grid count as 0 (empty space);
* the cameras are the dataparser's *training* views (the attack poisons training views), with poses and
  points as nerfstudio's dataparser outputs them (recentred, oriented and scaled consistently), so the
  ranking is in the same frame as training. Lens distortion is ignored (pinhole frustum).

Camera convention (nerfstudio / OpenGL): ``c2w`` maps camera to world; the camera looks along its local
``-Z`` axis, ``+Y`` is up and ``+X`` right; image coordinates ``(u, v)`` are continuous, with the image
covering ``[0, width] x [0, height]`` and ``v`` growing downwards.

Modules: :mod:`~stealth_ns.difficulty.protocol` (the math), :mod:`~stealth_ns.difficulty.ranking` (the
result, its table and files), :mod:`~stealth_ns.difficulty.dataset` (the training split through
nerfstudio's dataparsers), :mod:`~stealth_ns.difficulty.rank` (``rank_scene_views`` and the command).
"""
