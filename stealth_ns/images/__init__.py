"""Images: reading and writing them (:mod:`~stealth_ns.images.io`, one library), the metrics that
never crash a run (:mod:`~stealth_ns.images.metrics`) and the training loss's compiled SSIM
(:mod:`~stealth_ns.images.ssim`)."""
