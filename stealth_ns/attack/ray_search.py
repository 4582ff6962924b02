"""Rays through the illusion pixels of the poisoned view and the least-dense point along each ray.

Paper section 3.3, "Optimal Position Selection" (eq. 4): a ray ``C + t d`` is cast from the camera centre
``C`` through each pixel of the illusory object; the position of its poison Gaussian is

    x_min = argmin_{t in [t_min, t_max]} f(C + t d),

where ``f`` is the normalised KDE (:func:`stealth_ns.attack.density.gaussian_kde_grid`), ``t_min = 0.3``
(points right in front of the camera become floaters) and ``t_max`` the scene depth at the pixel.

Camera convention (nerfstudio / OpenGL): ``c2w`` maps camera to world coordinates; the camera looks down
its local ``-Z`` axis with ``+Y`` up and ``+X`` right; pixel ``(col, row)`` has its centre at
``(col + 0.5, row + 0.5)`` and row 0 is the top of the image.

Depth convention: ``t`` is the distance along the *unit* ray direction. A rendered z-depth ``z`` (distance
along the optical axis, what gsplat's ``"ED"``/``"D"`` render modes give) corresponds to
``t = z / cos_theta`` with ``cos_theta = d . (optical axis)``; :func:`pixel_rays` returns ``cos_theta`` and
:func:`zdepth_to_ray_t` does the conversion.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Generic, Literal, NamedTuple, TypeVar

import numpy as np
import torch

from stealth_ns.attack.density import DensityGrid, _sample_torch
from stealth_ns.attack.visibility import NEAR, CameraDepths, SeenPenalty

__all__ = ["PixelRays", "RaySearchResult", "pixel_rays", "zdepth_to_ray_t", "min_density_points"]

ArrayT = TypeVar("ArrayT", np.ndarray, torch.Tensor)

TieBreak = Literal["nearest-surface", "first", "middle"]

#: Default bound on rays x samples evaluated at once by :func:`min_density_points` (256 Ki samples).
#: The search's temporaries take ~200 bytes per sample, and with the malloc settings of training
#: (:mod:`stealth_ns.foundation.malloc_tuning`) the process keeps its peak for the rest of the run: on
#: the 1-MP ``facing`` scene 4 Mi samples made the step-0 injection raise the run's RSS from 1.2 to 2.07 GiB,
#: 256 Ki samples to 1.44 GiB, in the same injection time (docs/design/training_step.md).
MAX_SAMPLES_PER_CHUNK = 1 << 18


class PixelRays(NamedTuple):
    """Rays through pixel centres (all ``[M, ...]`` in world coordinates, scene units).

    Attributes:
        origins: ``[M, 3]`` camera centre, repeated per ray.
        directions: ``[M, 3]`` unit ray directions.
        cos_theta: ``[M]`` cosine between each ray and the optical axis (``directions . (-Z_cam)``), in
            ``(0, 1]``; ray parameter ``t = zdepth / cos_theta``.
    """

    origins: np.ndarray | torch.Tensor
    directions: np.ndarray | torch.Tensor
    cos_theta: np.ndarray | torch.Tensor


@dataclass(frozen=True, eq=False)
class RaySearchResult(Generic[ArrayT]):
    """Output of :func:`min_density_points` (same array type/device as the input rays).

    Attributes:
        points: ``[M, 3]`` the chosen point ``origin + t * direction`` per ray (NaN for invalid rays).
        t: ``[M]`` its ray parameter (NaN for invalid rays).
        density: ``[M]`` the sampled density there, i.e. the minimum along the ray (NaN for invalid rays).
        valid: ``[M]`` bool: ``t_min <= t_max`` and all inputs of the ray finite.
        penalty: ``[M]`` the ``penalty`` (see :func:`min_density_points`) at the chosen point, 0 without
            one (NaN for invalid rays).
    """

    points: ArrayT
    t: ArrayT
    density: ArrayT
    valid: ArrayT
    penalty: ArrayT

    def where(self, mask: ArrayT, other: RaySearchResult[ArrayT]) -> RaySearchResult[ArrayT]:
        """Per ray, ``other``'s result where ``mask`` ([M] bool) is set, this one's elsewhere."""
        lib = torch if isinstance(self.t, torch.Tensor) else np
        fields = ("points", "t", "density", "valid", "penalty")
        return RaySearchResult(
            *(
                lib.where(
                    mask[:, None] if name == "points" else mask, getattr(other, name), getattr(self, name)
                )
                for name in fields
            )
        )


def _to_torch(x, dtype=torch.float64, device=None) -> torch.Tensor:
    if isinstance(x, torch.Tensor):
        return x.to(device=device if device is not None else x.device)
    return torch.as_tensor(np.asarray(x, dtype=np.float64), dtype=dtype, device=device)


def pixel_rays(
    c2w: ArrayT,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    pixels: ArrayT,
) -> PixelRays:
    """World-space rays through the centres of the given pixels of a pinhole camera.

    The camera-space direction of pixel ``(u, v) = (col, row)`` is
    ``((u + 0.5 - cx) / fx, -(v + 0.5 - cy) / fy, -1)``, rotated to world by ``c2w[:3, :3]`` and normalised
    (identical to ``nerfstudio.cameras.cameras.Cameras.generate_rays`` for a perspective camera without
    distortion).

    Args:
        c2w: ``[3, 4]`` or ``[4, 4]`` camera-to-world matrix (OpenGL convention, see module docstring).
        fx, fy: focal lengths in pixels.
        cx, cy: principal point in pixels (image-coordinate units where pixel centres are at ``+0.5``).
        pixels: ``[M, 2]`` integer ``(col, row)`` pixel indices.

    Returns:
        :class:`PixelRays` ``(origins [M, 3], directions [M, 3], cos_theta [M])``; numpy input (float64)
        gives numpy output, a torch ``c2w`` gives tensors of its dtype and device.
    """
    is_numpy = not isinstance(c2w, torch.Tensor)
    m = _to_torch(c2w)
    if tuple(m.shape) not in ((3, 4), (4, 4)):
        raise ValueError(f"c2w must be [3, 4] or [4, 4], got {tuple(m.shape)}")
    if not torch.is_floating_point(m):
        m = m.double()
    px = _to_torch(pixels, dtype=m.dtype, device=m.device).to(m.dtype)
    if px.ndim != 2 or px.shape[1] != 2:
        raise ValueError(f"pixels must be [M, 2] (col, row), got {tuple(px.shape)}")
    if not all(math.isfinite(v) for v in (fx, fy, cx, cy)) or fx == 0 or fy == 0:
        raise ValueError(f"bad intrinsics fx={fx}, fy={fy}, cx={cx}, cy={cy}")
    x = (px[:, 0] + 0.5 - cx) / fx
    y = -(px[:, 1] + 0.5 - cy) / fy
    d_cam = torch.stack([x, y, -torch.ones_like(x)], dim=-1)
    norm = torch.linalg.norm(d_cam, dim=-1)
    d_cam = d_cam / norm[:, None]
    rot = m[:3, :3]
    directions = d_cam @ rot.T
    # Re-normalise in world space (c2w may carry a slight scale); cos_theta is measured in camera space.
    directions = directions / torch.linalg.norm(directions, dim=-1, keepdim=True)
    origins = m[:3, 3].expand_as(directions).clone()
    cos_theta = 1.0 / norm
    if is_numpy:
        return PixelRays(origins.numpy(), directions.numpy(), cos_theta.numpy())  # type: ignore[arg-type]
    return PixelRays(origins, directions, cos_theta)  # type: ignore[arg-type]


def zdepth_to_ray_t(zdepth: ArrayT, cos_theta: ArrayT) -> ArrayT:
    """Convert z-depth (along the optical axis) to the distance ``t`` along the unit ray: ``z / cos_theta``.

    Args:
        zdepth: ``[M]`` z-depth in scene units (e.g. the rendered ``"ED"`` depth at each pixel).
        cos_theta: ``[M]`` from :func:`pixel_rays`.

    Returns:
        ``[M]`` ray parameter ``t_max`` (same type as ``zdepth``).
    """
    return zdepth / cos_theta


def _ray_bound(value, m: int, dtype: torch.dtype, device: torch.device, name: str) -> torch.Tensor:
    """Scalar or ``[M]`` (any shape with M elements) bound -> ``[M]`` tensor."""
    t = _to_torch(value, device=device).to(dtype)
    if t.numel() == 1:
        return t.reshape(()).expand(m)
    if t.numel() != m:
        raise ValueError(
            f"{name} must be a scalar or have one value per ray ({m}), got shape {tuple(t.shape)}"
        )
    return t.reshape(m)


def _pick_index(f: torch.Tensor, tie_break: str, tie_tol: float) -> torch.Tensor:
    """Index (per row of ``f`` [C, n]) of the minimum under the tie-break rule; NaNs never win."""
    n = f.shape[1]
    f = torch.nan_to_num(f, nan=float("inf"))
    fmin = f.min(dim=1, keepdim=True).values
    cand = f <= fmin + tie_tol  # within tolerance of the minimum
    ar = torch.arange(n, device=f.device)
    first = torch.argmax(cand.to(torch.uint8), dim=1)
    if tie_break == "first":
        return first
    if tie_break == "nearest-surface":
        return n - 1 - torch.argmax(cand.flip(1).to(torch.uint8), dim=1)
    # "middle" of the first run of candidates: the run ends just before the first non-candidate after it.
    after = (~cand) & (ar[None, :] > first[:, None])
    has_end = after.any(dim=1)
    end = torch.where(has_end, torch.argmax(after.to(torch.uint8), dim=1) - 1, torch.full_like(first, n - 1))
    return torch.div(first + end, 2, rounding_mode="floor")


class _Rays(NamedTuple):
    """The valid rays of a search (``[V, 3]``, ``[V]``) and the samples' fractions ``[n]`` of
    ``[t_min, t_max]``."""

    origins: torch.Tensor
    directions: torch.Tensor
    t_min: torch.Tensor
    t_max: torch.Tensor
    frac: torch.Tensor


class _Rule(NamedTuple):
    """How a search chooses (see :func:`min_density_points`)."""

    tie_break: str
    tie_tol: float
    mode: str
    outside: float
    penalty: Callable[[torch.Tensor], torch.Tensor] | None


#: The compiled search's codes of the tie-break rules.
_TIE_BREAK_CODES = {"nearest-surface": 0, "first": 1, "middle": 2}


def _extension() -> Any:
    """The compiled module, or None where it is unavailable."""
    from stealth_ns.raster.cpp_backend import load_extension

    return load_extension()


def _search_torch(
    density: DensityGrid, rays: _Rays, rule: _Rule, max_samples_per_chunk: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per ray: the chosen sample's index ``[V]``, its density and its penalty (the readable path)."""
    tie_break, tie_tol, mode, outside, penalty = rule
    o = rays.origins
    values = torch.from_numpy(density.values).to(o.device)
    origin = torch.as_tensor(density.origin, dtype=o.dtype, device=o.device)
    chunk = max(1, max_samples_per_chunk // rays.frac.numel())
    ks, fs, pens = [], [], []
    for start in range(0, o.shape[0], chunk):
        c = slice(start, start + chunk)
        tn, tf = rays.t_min[c], rays.t_max[c]
        ts = tn[:, None] + (tf - tn)[:, None] * rays.frac[None, :]  # [C, n]
        pts = o[c, None, :] + ts[..., None] * rays.directions[c, None, :]  # [C, n, 3]
        f = _sample_torch(values, origin, density.voxel_size, pts, mode, outside)  # [C, n]
        pen = penalty(pts).to(o.dtype) if penalty is not None else torch.zeros_like(f)
        del pts
        k = _pick_index(2.0 * pen + f, tie_break, tie_tol)
        ks.append(k)
        fs.append(f.gather(1, k[:, None])[:, 0])
        pens.append(pen.gather(1, k[:, None])[:, 0])
    return torch.cat(ks), torch.cat(fs), torch.cat(pens)


def _search_compiled(
    density: DensityGrid, rays: _Rays, rule: _Rule
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None:
    """:func:`_search_torch`'s result from one compiled pass (``raster/csrc/ray_search_cpu.cpp``), or
    None where that does not apply: float32 rays on the CPU, nearest-voxel lookup, no penalty or a
    :class:`SeenPenalty`, the extension built."""
    tie_break, tie_tol, mode, outside, penalty = rule
    if rays.origins.device.type != "cpu" or rays.origins.dtype != torch.float32 or mode != "nearest":
        return None
    if penalty is not None and not isinstance(penalty, SeenPenalty):
        return None
    ext = _extension()
    if ext is None:
        return None
    none = CameraDepths(torch.zeros(0, 4, 4), torch.zeros(0, 3, 3), [], [])
    margin = penalty.margin if penalty is not None else 0.0
    cameras = []  # innocent, then support: viewmats, Ks, depth bounds
    for group in (penalty.innocent, penalty.support) if penalty is not None else (None, None):
        group = group if group is not None else none
        cameras += [group.viewmats.float().contiguous(), group.Ks.float().contiguous()]
        cameras.append(group.depth_bounds(margin))
    return ext.ray_search(
        *(t.contiguous() for t in rays),
        torch.from_numpy(density.values).contiguous(),
        torch.as_tensor(density.origin, dtype=torch.float32),
        density.voxel_size,
        outside,
        *cameras,
        NEAR,
        _TIE_BREAK_CODES[tie_break],
        tie_tol,
    )


def min_density_points(
    density: DensityGrid,
    origins: ArrayT,
    directions: ArrayT,
    t_min: float | ArrayT,
    t_max: float | ArrayT,
    n_samples: int = 1024,
    tie_break: TieBreak = "nearest-surface",
    tie_tol: float = 1e-6,
    mode: Literal["nearest", "trilinear"] = "nearest",
    outside: float = 0.0,
    max_samples_per_chunk: int = MAX_SAMPLES_PER_CHUNK,
    penalty: Callable[[torch.Tensor], torch.Tensor] | None = None,
) -> RaySearchResult[ArrayT]:
    """Least-dense point along each ray (paper eq. 4), by dense uniform sampling.

    Each valid ray is sampled at ``n_samples`` values of ``t`` spaced uniformly over ``[t_min, t_max]``
    (both ends included; the authors used 8192 samples with nearest-voxel lookup); the density is read with
    :func:`stealth_ns.attack.density.sample_grid` semantics (``outside`` beyond the grid). The minimum is
    usually not unique -- every sample in empty space (outside the grid, or beyond the KDE kernel's reach)
    reads exactly 0 -- so the rule among the *candidates*, samples within ``tie_tol`` (absolute, on the
    normalised KDE) of the ray's minimum, matters:

    * ``"first"``: the candidate nearest ``t_min`` (numpy ``argmin`` behaviour, the authors' code). In empty
      space this puts the poison right in front of the camera, where densification / pruning treat it as a
      floater and every nearby innocent view sees it.
    * ``"nearest-surface"`` (default): the candidate nearest ``t_max``. In empty space the poison lands just
      in front of the scene surface the pixel shows, i.e. inside the scene's own geometry envelope and at a
      depth consistent with it (a realistic illusion that is occluded from most side views, rather than a
      camera-hugging floater); in an occluded low-density pocket it is the pocket's far end.
    * ``"middle"``: the middle sample of the first contiguous run of candidates (the centre of the first
      low-density pocket; ``(start + end) // 2``).

    ``penalty`` (optional) maps sample points ``[C, n, 3]`` (torch, the rays' dtype/device) to a
    non-negative integer cost ``[C, n]``, e.g. the number of innocent cameras that see each point
    (:func:`stealth_ns.attack.visibility.count_seeing_cameras`). The search then minimises
    ``(penalty, density)`` lexicographically -- the fewest-penalty samples first, the density (a
    normalised KDE, in [0, 1]) among them, the tie-break rule last -- by minimising
    ``2 * penalty + density``.

    On the CPU, for float32 rays with ``mode="nearest"`` and no penalty or a :class:`SeenPenalty`, one
    compiled pass does the search (``raster/csrc/ray_search_cpu.cpp``, with the same result); the torch
    code below is its reference and the path everywhere else.

    Chunking: rays are processed in chunks of ``max(1, max_samples_per_chunk // n_samples)`` rays so that
    at most ``max_samples_per_chunk`` sample points (``[chunk, n, 3]``) exist at a time; results do not
    depend on the chunk size.

    Args:
        density: the (normalised) KDE grid.
        origins: ``[M, 3]`` ray origins (world, scene units); numpy array or torch tensor (any device).
        directions: ``[M, 3]`` unit ray directions.
        t_min: scalar or ``[M]`` near bound (paper: 0.3).
        t_max: scalar or ``[M]`` far bound, the scene depth along the ray (see :func:`zdepth_to_ray_t`).
        n_samples: samples per ray (>= 1; with 1 the sample is ``t_min``).
        tie_break: ``"nearest-surface"``, ``"first"`` or ``"middle"`` (see above).
        tie_tol: absolute tolerance (>= 0) defining the minimal candidates.
        mode: density lookup, ``"nearest"`` or ``"trilinear"``.
        outside: density of points outside the grid.
        max_samples_per_chunk: memory bound, see above.
        penalty: optional per-sample integer cost minimised before the density (see above).

    Returns:
        :class:`RaySearchResult` with ``points [M, 3]``, ``t [M]``, ``density [M]`` (NaN for invalid rays)
        and ``valid [M]`` bool (``t_min <= t_max`` and finite inputs). Same array type as ``origins``;
        torch outputs use the dtype of ``origins`` (float32 or float64), numpy outputs float64.
    """
    if tie_break not in ("nearest-surface", "first", "middle"):
        raise ValueError(f"tie_break must be 'nearest-surface', 'first' or 'middle', got {tie_break!r}")
    if mode not in ("nearest", "trilinear"):
        raise ValueError(f"mode must be 'nearest' or 'trilinear', got {mode!r}")
    if isinstance(n_samples, bool) or int(n_samples) != n_samples or n_samples < 1:
        raise ValueError(f"n_samples must be a positive integer, got {n_samples!r}")
    if not (math.isfinite(tie_tol) and tie_tol >= 0):
        raise ValueError(f"tie_tol must be a non-negative number, got {tie_tol!r}")
    if int(max_samples_per_chunk) < 1:
        raise ValueError(f"max_samples_per_chunk must be >= 1, got {max_samples_per_chunk!r}")
    n = int(n_samples)

    is_numpy = not isinstance(origins, torch.Tensor)
    o = _to_torch(origins)
    if not torch.is_floating_point(o):
        o = o.double()
    dtype, device = o.dtype, o.device
    d = _to_torch(directions, device=device).to(dtype)
    if o.ndim != 2 or o.shape[1] != 3 or d.shape != o.shape:
        raise ValueError(
            f"origins and directions must both be [M, 3], got {tuple(o.shape)} and {tuple(d.shape)}"
        )
    m = o.shape[0]
    tn = _ray_bound(t_min, m, dtype, device, "t_min")
    tf = _ray_bound(t_max, m, dtype, device, "t_max")

    finite = torch.isfinite(o).all(1) & torch.isfinite(d).all(1) & torch.isfinite(tn) & torch.isfinite(tf)
    valid = finite & (tn <= tf)
    points = torch.full((m, 3), float("nan"), dtype=dtype, device=device)
    t_out = torch.full((m,), float("nan"), dtype=dtype, device=device)
    f_out = torch.full((m,), float("nan"), dtype=dtype, device=device)
    pen_out = torch.full((m,), float("nan"), dtype=dtype, device=device)

    vidx = torch.nonzero(valid).flatten()
    if vidx.numel():
        frac = (
            torch.linspace(0.0, 1.0, n, dtype=dtype, device=device)
            if n > 1
            else torch.zeros(1, dtype=dtype, device=device)
        )
        rays = _Rays(o[vidx], d[vidx], tn[vidx], tf[vidx], frac)
        rule = _Rule(tie_break, tie_tol, mode, float(outside), penalty)
        found = _search_compiled(density, rays, rule)
        if found is None:
            found = _search_torch(density, rays, rule, int(max_samples_per_chunk))
        k, f_k, pen_k = found
        f_out[vidx], pen_out[vidx] = f_k.to(dtype), pen_k.to(dtype)
        t_best = rays.t_min + (rays.t_max - rays.t_min) * frac[k]  # the chosen sample's t, as sampled
        t_out[vidx] = t_best
        points[vidx] = rays.origins + t_best[:, None] * rays.directions

    if is_numpy:
        return RaySearchResult(points.numpy(), t_out.numpy(), f_out.numpy(), valid.numpy(), pen_out.numpy())  # type: ignore[arg-type]
    return RaySearchResult(points, t_out, f_out, valid, pen_out)  # type: ignore[arg-type]
