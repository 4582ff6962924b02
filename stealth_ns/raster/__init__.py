"""3D Gaussian rasterization with gsplat's contract: CUDA (gsplat), compiled CPU and pure-PyTorch backends."""

from stealth_ns.raster.rasterization import Backend, blend_weights, rasterization, resolve_backend

__all__ = ["Backend", "blend_weights", "rasterization", "resolve_backend"]
