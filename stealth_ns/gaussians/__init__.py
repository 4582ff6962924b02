"""The Gaussians' representation, as pure functions: initial rows (:mod:`~stealth_ns.gaussians.init`),
the model files (:mod:`~stealth_ns.gaussians.model_files`: the 3DGS PLY of
:mod:`~stealth_ns.gaussians.ply`, the compressed PLY, ``.splat`` and ``.spz``), the one place that
changes rows together with their training state (:mod:`~stealth_ns.gaussians.rows`) and similarity
transforms between world frames (:mod:`~stealth_ns.gaussians.transform`)."""
