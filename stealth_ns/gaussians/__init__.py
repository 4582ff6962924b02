"""The Gaussians' representation, as pure functions: initial rows (:mod:`~stealth_ns.gaussians.init`),
the 3DGS PLY file (:mod:`~stealth_ns.gaussians.ply`), the one place that changes rows together with
their training state (:mod:`~stealth_ns.gaussians.rows`) and similarity transforms between world
frames (:mod:`~stealth_ns.gaussians.transform`)."""
