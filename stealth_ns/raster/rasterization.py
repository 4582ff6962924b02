"""``rasterization``: gsplat's call contract with a choice of backend.

Backends:
  - ``"gsplat"``: gsplat's CUDA kernels (tensors on a CUDA device);
  - ``"cpp"``: the compiled CPU kernel (``cpp_backend``), built on first use;
  - ``"torch"``: the pure-PyTorch reference (``torch_backend``), slow but readable;
  - ``"auto"``: gsplat on CUDA tensors, otherwise cpp if it compiles, else torch (with one
    warning saying why).

The CPU path: projection and SH colour (compiled, ``cpp_backend.project_gaussians_cpp`` and
``sh_colors_cpp``, on the ``cpp`` backend unless the cameras need a gradient; else the torch
reference ``projection``), tile intersection (``tiles``), then the chosen CPU rasterize-to-pixels
kernel. The returned ``info`` has
what gsplat's ``DefaultStrategy`` reads: ``means2d`` (non-leaf, so its gradient can be
retained), ``radii [C, N]``, ``width``, ``height``, ``n_cameras``, ``gaussian_ids=None``.
"""

from __future__ import annotations

import warnings
from typing import Literal

import torch
from torch import Tensor

from stealth_ns.foundation.step_timing import phase
from stealth_ns.raster.projection import (
    SHCoefficients,
    join_sh,
    project_gaussians,
    quat_scale_to_covar,
    spherical_harmonics,
)
from stealth_ns.raster.tiles import Footprint, isect_tiles, tile_grid
from stealth_ns.raster.torch_backend import rasterize_to_pixels_torch

Backend = Literal["auto", "gsplat", "cpp", "torch"]
RenderMode = Literal["RGB", "D", "ED", "RGB+D", "RGB+ED"]

_warned_fallback = False


def resolve_backend(backend: Backend, device: torch.device) -> str:
    """The concrete backend ``"gsplat" | "cpp" | "torch"`` that ``backend`` means on ``device``."""
    if backend == "auto":
        if device.type == "cuda":
            return "gsplat"
        return "cpp" if cpp_available() else "torch"
    if backend == "gsplat" and device.type != "cuda":
        raise ValueError("the gsplat backend needs CUDA tensors; use backend 'cpp' or 'torch' on CPU")
    if backend == "cpp" and not cpp_available():
        from stealth_ns.raster import cpp_backend

        raise RuntimeError(f"the compiled CPU rasterizer is unavailable: {cpp_backend.compile_error()}")
    return backend


def cpp_available() -> bool:
    """True when the compiled CPU kernel builds (or is cached); warns once when it does not."""
    global _warned_fallback
    try:
        from stealth_ns.raster import cpp_backend
    except ImportError as err:  # pragma: no cover - only when the module itself is missing
        reason = str(err)
        ok = False
    else:
        ok = cpp_backend.load_extension() is not None
        reason = "" if ok else str(cpp_backend.compile_error())
    if not ok and not _warned_fallback:
        warnings.warn(
            f"stealth-ns: compiled CPU rasterizer unavailable ({reason}); using the slow pure-PyTorch one",
            RuntimeWarning,
            stacklevel=3,
        )
        _warned_fallback = True
    return ok


def rasterization(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    colors: Tensor | SHCoefficients,
    viewmats: Tensor,
    Ks: Tensor,
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    radius_clip: float = 0.0,
    eps2d: float = 0.3,
    sh_degree: int | None = None,
    packed: bool = False,
    tile_size: int = 16,
    backgrounds: Tensor | None = None,
    render_mode: RenderMode = "RGB",
    absgrad: bool = False,
    rasterize_mode: Literal["classic", "antialiased"] = "classic",
    backend: Backend = "auto",
    **gsplat_kwargs,
) -> tuple[Tensor, Tensor, dict]:
    """Render Gaussians into C cameras (gsplat's ``rasterization`` contract).

    Args:
        means: [N, 3]; quats: [N, 4] (w, x, y, z); scales: [N, 3] (not log);
        opacities: [N] in [0, 1].
        colors: [N, D] features, or SH coefficients when ``sh_degree`` is set: [N, K, 3], or the
            pair (dc [N, 3], rest [N, K - 1, 3]) as nerfstudio stores them (see ``SHCoefficients``).
        viewmats: [C, 4, 4] world-to-camera (OpenCV); Ks: [C, 3, 3].
        width, height: image size in pixels.
        render_mode: "RGB", "D" (accumulated depth), "ED" (expected depth), "RGB+D", "RGB+ED".
        backgrounds: [C, D] (colour channels only).
        backend: see module docstring.

    Returns:
        render_colors [C, H, W, D'], render_alphas [C, H, W, 1], info dict.
    """
    name = resolve_backend(backend, means.device)
    if name == "gsplat":
        from gsplat.rendering import rasterization as gsplat_rasterization

        with phase("rasterize forward"):  # gsplat's projection, tile sort and kernel are one call
            return gsplat_rasterization(
                means=means,
                quats=quats,
                scales=scales,
                opacities=opacities,
                colors=join_sh(colors),
                viewmats=viewmats,
                Ks=Ks,
                width=width,
                height=height,
                near_plane=near_plane,
                far_plane=far_plane,
                radius_clip=radius_clip,
                eps2d=eps2d,
                sh_degree=sh_degree,
                packed=packed,
                tile_size=tile_size,
                backgrounds=backgrounds,
                render_mode=render_mode,
                absgrad=absgrad,
                rasterize_mode=rasterize_mode,
                **gsplat_kwargs,
            )
    if absgrad:
        raise ValueError("absgrad is only computed by gsplat's CUDA backward; use absgrad=False on CPU")
    if rasterize_mode != "classic":
        raise ValueError("the CPU rasterizers implement rasterize_mode='classic' only")
    return _rasterize_cpu(
        name,
        means,
        quats,
        scales,
        opacities,
        colors,
        viewmats,
        Ks,
        width,
        height,
        near_plane=near_plane,
        far_plane=far_plane,
        radius_clip=radius_clip,
        eps2d=eps2d,
        sh_degree=sh_degree,
        tile_size=tile_size,
        backgrounds=backgrounds,
        render_mode=render_mode,
    )


def blend_weights(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    viewmats: Tensor,
    Ks: Tensor,
    width: int,
    height: int,
    near_plane: float = 0.01,
    with_depth: bool = False,
    tile_size: int = 16,
    rasterize_mode: Literal["classic", "antialiased"] = "classic",
    backend: Backend = "auto",
) -> tuple[Tensor, Tensor | None, Tensor]:
    """Every Gaussian's alpha-blending weight in each camera: the sum over the camera's pixels of
    ``T_i * alpha_i``, the share of the pixel the Gaussian paints (0 when culled or fully hidden).

    Arguments as :func:`rasterization` (no gradient flows). The compiled CPU backend sums the weights
    as it blends (one forward pass); the others read them off the renderer as the gradient of the
    rendered image's sum with respect to a per-camera, per-Gaussian colour (forward and backward),
    which is the same sum on every backend.

    Returns:
        weights ``[C, N]``; the expected z-depth ``[C, H, W]`` as the ``"ED"`` render mode gives it
        (``None`` unless ``with_depth``); the opacity ``[C, H, W]``.
    """
    name = resolve_backend(backend, means.device)
    C, N = viewmats.shape[0], means.shape[0]
    if name == "cpp" and rasterize_mode == "classic":
        return _cpp_blend_weights(
            means, quats, scales, opacities, viewmats, Ks, width, height, near_plane, with_depth, tile_size
        )
    with torch.enable_grad():
        probe = torch.zeros(C, N, 1, device=means.device, requires_grad=True)
        render, alpha, _ = rasterization(
            means.detach(),
            quats.detach(),
            scales.detach(),
            opacities.detach(),
            probe.expand(-1, -1, 3),
            viewmats,
            Ks,
            width,
            height,
            near_plane=near_plane,
            tile_size=tile_size,
            render_mode="RGB+ED" if with_depth else "RGB",
            rasterize_mode=rasterize_mode,
            backend=name,
        )
        (grad,) = torch.autograd.grad(render[..., 0].sum(), probe)
    depth = render[..., 3].detach() if with_depth else None
    return grad[..., 0], depth, alpha[..., 0].detach()


@torch.no_grad()
def _cpp_blend_weights(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    viewmats: Tensor,
    Ks: Tensor,
    width: int,
    height: int,
    near_plane: float,
    with_depth: bool,
    tile_size: int,
) -> tuple[Tensor, Tensor | None, Tensor]:
    """:func:`blend_weights` with the compiled kernels: projection, tile sort, one forward."""
    from stealth_ns.raster.cpp_backend import isect_tiles_cpp, project_gaussians_cpp, rasterize_weights_cpp

    C = viewmats.shape[0]
    radii, means2d, depths, conics = project_gaussians_cpp(
        means, quats, scales, viewmats, Ks, width, height, near_plane=near_plane
    )
    opac = opacities[None, :].expand(C, -1).contiguous()
    tile_width, tile_height = tile_grid(width, height, tile_size)
    footprint = Footprint(conics, opac, width, height)
    offsets, flatten_ids = isect_tiles_cpp(
        means2d, radii, depths, tile_size, tile_width, tile_height, footprint
    )
    feats = depths[..., None] if with_depth else depths.new_zeros(C, means.shape[0], 1)
    render, alpha, weights = rasterize_weights_cpp(
        means2d, conics, feats, opac, width, height, tile_size, offsets, flatten_ids
    )
    depth = (render / alpha.clamp(min=1e-10))[..., 0] if with_depth else None
    return weights, depth, alpha[..., 0]


def _rasterize_cpu(
    name: str,
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    colors: Tensor | SHCoefficients,
    viewmats: Tensor,
    Ks: Tensor,
    width: int,
    height: int,
    *,
    near_plane: float,
    far_plane: float,
    radius_clip: float,
    eps2d: float,
    sh_degree: int | None,
    tile_size: int,
    backgrounds: Tensor | None,
    render_mode: RenderMode,
) -> tuple[Tensor, Tensor, dict]:
    """:func:`rasterization` on the CPU backend ``name`` (``"cpp"`` or ``"torch"``): projection, the
    per-camera features, tile intersection, rasterize-to-pixels; the info dict gsplat's strategy reads."""
    C = viewmats.shape[0]
    # the compiled projection and SH have no gradient for the cameras (a camera optimizer needs the reference)
    fused = name == "cpp" and not (viewmats.requires_grad or Ks.requires_grad)
    with phase("projection+SH"):
        if fused:
            from stealth_ns.raster.cpp_backend import project_gaussians_cpp

            radii, means2d, depths, conics = project_gaussians_cpp(
                means, quats, scales, viewmats, Ks, width, height, eps2d, near_plane, far_plane, radius_clip
            )
        else:
            covars = quat_scale_to_covar(quats, scales)
            radii, means2d, depths, conics = project_gaussians(
                means, covars, viewmats, Ks, width, height, eps2d, near_plane, far_plane, radius_clip
            )
        opac = opacities[None, :].expand(C, -1)
        feats, backgrounds = _camera_features(
            means, colors, viewmats, depths, sh_degree, backgrounds, render_mode, radii if fused else None
        )

    tile_width, tile_height = tile_grid(width, height, tile_size)
    isect, raster = _cpu_kernels(name)
    with phase("tile sort"):
        # only the tiles each Gaussian's alpha >= 1/255 footprint reaches: the same pixels, fewer visits
        opac_rows = opac.contiguous()  # [C, N], as the rasterizer blends them
        footprint = Footprint(conics.detach(), opac_rows.detach(), width, height)
        isect_offsets, flatten_ids = isect(
            means2d, radii, depths, tile_size, tile_width, tile_height, footprint
        )
    with phase("rasterize forward"):
        render_colors, render_alphas = raster(
            means2d,
            conics,
            feats.contiguous(),
            opac_rows,
            width,
            height,
            tile_size,
            isect_offsets,
            flatten_ids,
            backgrounds,
        )
    if render_mode in ("ED", "RGB+ED"):
        expected = render_colors[..., -1:] / render_alphas.clamp(min=1e-10)
        render_colors = torch.cat([render_colors[..., :-1], expected], dim=-1)

    info = {
        "camera_ids": None,
        "gaussian_ids": None,
        "radii": radii,
        "means2d": means2d,
        "depths": depths,
        "conics": conics,
        "opacities": opac,
        "tile_width": tile_width,
        "tile_height": tile_height,
        "isect_offsets": isect_offsets,
        "flatten_ids": flatten_ids,
        "width": width,
        "height": height,
        "tile_size": tile_size,
        "n_cameras": C,
        "backend": name,
    }
    return render_colors, render_alphas, info


def _camera_features(
    means: Tensor,
    colors: Tensor | SHCoefficients,
    viewmats: Tensor,
    depths: Tensor,
    sh_degree: int | None,
    backgrounds: Tensor | None,
    render_mode: RenderMode,
    compiled_radii: Tensor | None = None,
) -> tuple[Tensor, Tensor | None]:
    """What each camera blends per Gaussian, ``[C, N, D']``, and the matching backgrounds ``[C, D']``:
    the colours (SH evaluated towards the camera when ``sh_degree`` is set, + 0.5, clamped at 0),
    with the depth appended for ``RGB+D`` / ``RGB+ED``, or the depth alone for ``D`` / ``ED``
    (background 0). With ``compiled_radii`` ``[C, N]`` the SH colours come from the compiled kernel
    (0 for Gaussians of radius 0, which are not drawn)."""
    C = viewmats.shape[0]
    shared = not isinstance(colors, Tensor) or colors.dim() == 3  # not per-camera [C, N, K, 3]
    if sh_degree is not None and compiled_radii is not None and shared:
        from stealth_ns.raster.cpp_backend import sh_colors_cpp

        feats = sh_colors_cpp(means, viewmats, colors, sh_degree, compiled_radii)
    elif sh_degree is not None:
        campos = torch.linalg.inv(viewmats)[:, :3, 3]
        dirs = means[None, :, :] - campos[:, None, :]
        coeffs = join_sh(colors)
        coeffs = coeffs if coeffs.dim() == 4 else coeffs[None].expand(C, -1, -1, -1)
        feats = torch.clamp_min(spherical_harmonics(sh_degree, dirs, coeffs) + 0.5, 0.0)
    else:
        assert isinstance(colors, Tensor), "split SH coefficients need sh_degree"
        feats = colors if colors.dim() == 3 else colors[None].expand(C, -1, -1)

    if render_mode in ("RGB+D", "RGB+ED"):
        feats = torch.cat([feats, depths[..., None]], dim=-1)
        if backgrounds is not None:
            backgrounds = torch.cat([backgrounds, backgrounds.new_zeros(C, 1)], dim=-1)
    elif render_mode in ("D", "ED"):
        feats = depths[..., None]
        if backgrounds is not None:
            backgrounds = backgrounds.new_zeros(C, 1)
    return feats, backgrounds


def _cpu_kernels(name: str):
    """(tile intersection, rasterize-to-pixels) of a CPU backend; both give identical results."""
    if name == "cpp":
        from stealth_ns.raster.cpp_backend import isect_tiles_cpp, rasterize_to_pixels_cpp

        return isect_tiles_cpp, rasterize_to_pixels_cpp
    return isect_tiles, rasterize_to_pixels_torch
