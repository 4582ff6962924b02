"""Per-Gaussian, per-training-view signals read off a trained model: what a defender can measure.

Both return a ``[N, V]`` matrix (N Gaussians, V training views) that
:func:`stealth_ns.defences.scores.concentration_scores` turns into a suspicion score:

* :func:`view_weight_matrix` -- how much of each view each Gaussian paints (its accumulated
  alpha-blending weight, from the renderer: :meth:`StealthSplatModel.blend_weights`);
* :func:`gradient_energy_matrix` -- training dynamics: during a short fine-tune on the training
  images, how much of each Gaussian's gradient comes from each view.

and, from :mod:`stealth_ns.method.camera_geometry`, the cameras with the depth of what each shows, from
which :func:`frustum_depth_ratios` measures how close a Gaussian floats in front of a camera
(camera-proximity): the compiled kernel (``raster/csrc/frustum_cpu.cpp``) with the contract of its numpy
reference, :func:`stealth_ns.defences.scores.frustum_depth_ratios`.

Poison is meant to be seen from one view, so its support and its gradient concentrate in it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from stealth_ns.attack.injection import surface_depths
from stealth_ns.defences import scores
from stealth_ns.method.model import POISON_TAG, StealthSplatModel
from stealth_ns.raster.cpp_backend import load_extension


def _progress(total: int, desc: str):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="view", leave=False, disable=None)


def frustum_depth_ratios(
    means: np.ndarray, viewmats: np.ndarray, Ks: np.ndarray, sizes: np.ndarray, scene_depths: np.ndarray
) -> np.ndarray:
    """:func:`stealth_ns.defences.scores.frustum_depth_ratios` (its arguments, checks and result), by the
    compiled kernel when it is available (one pass over the centres, every camera per block of them,
    instead of a dozen full-size numpy operations per camera), else by that numpy reference."""
    ext = load_extension()
    if ext is None:
        return scores.frustum_depth_ratios(means, viewmats, Ks, sizes, scene_depths)
    checked = scores.check_frustum_arguments(means, viewmats, Ks, sizes, scene_depths)
    tensors = [torch.from_numpy(np.ascontiguousarray(a)) for a in checked]
    return ext.frustum_depth_ratios(*tensors).numpy()


@torch.no_grad()
def view_weight_matrix(model: StealthSplatModel, cameras: object, desc: str = "view support") -> np.ndarray:
    """``[N, V]`` float32: accumulated alpha-blending weight of every Gaussian in every camera of
    ``cameras`` (a nerfstudio ``Cameras`` of V views), in pixels (1 = one full pixel's worth).

    Each column sums to the view's summed opacity (``accumulation``) over its pixels."""
    return view_weights_and_depths(model, cameras, desc, with_depths=False)[0]


#: Views whose weights :func:`view_weights_and_depths` gathers before writing them into its matrix.
WEIGHT_BLOCK_VIEWS = 16

#: The quantile of a view's surface depths that stands for the nearest things it shows: low enough
#: for the near walls and floor of a walk-through to count, above the few pixels of a stray floater.
NEAR_DEPTH_QUANTILE = 0.05


def surface_median_and_near(depth: Tensor, alpha: Tensor) -> tuple[float, float]:
    """``(median, near)`` rendered z-depths (scene units) of the pixels of one view (``[H, W]`` each) that
    show a surface (:func:`~stealth_ns.attack.injection.surface_depths`), from one selection and one
    partition: the lower median, as :func:`~stealth_ns.attack.injection.median_scene_depth` takes it,
    and the near depth, the :data:`NEAR_DEPTH_QUANTILE` quantile (the k-th nearest, k rounded up);
    NaN, NaN when no pixel shows one."""
    surface = surface_depths(depth, alpha).reshape(-1).cpu().numpy()
    n = surface.size
    if n == 0:
        return math.nan, math.nan
    median, near = (n + 1) // 2 - 1, max(1, math.ceil(NEAR_DEPTH_QUANTILE * n)) - 1
    ordered = np.partition(surface, sorted({median, near}))
    return float(ordered[median]), float(ordered[near])


def near_depth_share(medians: np.ndarray, nears: np.ndarray) -> float:
    """The scene's near depth as a share of a view's median depth: the median over the views (``[V]``
    each, NaN where a view shows no surface) of ``nears / medians``; 1.0 when no view shows a surface.
    A median over the views, so that one view filled by something close (an illusion) moves it little."""
    medians, nears = np.asarray(medians, dtype=np.float64), np.asarray(nears, dtype=np.float64)
    ok = np.isfinite(medians) & np.isfinite(nears) & (medians > 0)
    return float(np.median(nears[ok] / medians[ok])) if ok.any() else 1.0


@torch.no_grad()
def view_weights_and_depths(
    model: StealthSplatModel, cameras: object, desc: str = "view support", with_depths: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`view_weight_matrix`'s ``[N, V]`` weights, ``[V]`` each view's median rendered z-depth
    of the pixels that show a surface (:func:`~stealth_ns.attack.injection.median_scene_depth`, NaN
    where none does; all NaN without ``with_depths``) and ``[V]`` each view's near depth
    (:func:`surface_median_and_near`, NaN likewise), read off the same renders: camera-proximity's scene
    depths (:func:`stealth_ns.method.camera_geometry.geometry_of`) without rendering again."""
    n_views = len(cameras)
    out = np.zeros((model.num_points, n_views), dtype=np.float32)
    depths = np.full(n_views, np.nan)
    nears = np.full(n_views, np.nan)
    # a block of views' weights is written into ``out`` at once: one column at a time would touch
    # every row's cache line once per view
    block = np.empty((min(WEIGHT_BLOCK_VIEWS, n_views), model.num_points), dtype=np.float32)
    with _progress(n_views, desc) as bar:
        for v in range(n_views):
            if with_depths:
                weights, depth, alpha = model.blend_weights(cameras[v : v + 1], with_depth=True)
                depths[v], nears[v] = surface_median_and_near(depth, alpha)
            else:
                weights = model.blend_weights(cameras[v : v + 1])
            block[v % len(block)] = weights.cpu().numpy()
            if v % len(block) == len(block) - 1 or v == n_views - 1:
                first = v - v % len(block)
                out[:, first : v + 1] = block[: v + 1 - first].T
            bar.update(1)
    return out, depths, nears


@dataclass(frozen=True)
class FineTune:
    """The short fine-tune of :func:`gradient_energy_matrix`."""

    epochs: int = 2
    """Passes over the training views (each view once per pass, in a seeded random order)."""
    lr_scale: float = 1.0
    """Multiplies ``learning_rates`` (the run's final per-parameter rates)."""
    seed: int = 0
    """Order of the views."""


def _view_loss(model: StealthSplatModel, camera: object, image: Tensor) -> Tensor:
    """Mean L1 between the render of ``camera`` and ``image`` ([H, W, 3 or 4], as cached), with
    gradients; images with alpha are composited onto the model's background as training does."""
    outputs = model.get_outputs(camera.to(model.device))
    gt = model.composite_with_background(model.get_gt_img(image), outputs["background"])
    return (outputs["rgb"] - gt).abs().mean()


def gradient_energy_matrix(
    model: StealthSplatModel,
    cameras: object,
    images: Sequence[Tensor],
    learning_rates: dict[str, float],
    tune: FineTune = FineTune(),
) -> np.ndarray:
    """``[N, V]`` float32: per Gaussian and training view, the summed squared gradient of the view's
    L1 loss with respect to the Gaussian's parameters (all of them: position, scale, rotation,
    colour, opacity) over a short fine-tune of ``tune.epochs`` passes, one Adam step per view.

    The model is fine-tuned in evaluation mode (no densification) and put back exactly as it was
    afterwards. ``images[v]`` is view v's training image as the datamanager caches it
    (``[H, W, C]``, uint8 or float); ``learning_rates`` gives each of :data:`TRAINABLE` its Adam rate.
    """
    energy = np.zeros((model.num_points, len(cameras)), dtype=np.float64)
    order = np.random.default_rng(tune.seed)
    with model.trial_parameters() as (params, _):
        optimizer = torch.optim.Adam(
            [{"params": [p], "lr": learning_rates[k] * tune.lr_scale} for k, p in params.items()], eps=1e-15
        )
        with _progress(tune.epochs * len(cameras), "training dynamics") as bar:
            for _ in range(tune.epochs):
                for v in order.permutation(len(cameras)):
                    optimizer.zero_grad(set_to_none=True)
                    with torch.enable_grad():
                        _view_loss(model, cameras[int(v) : int(v) + 1], images[v]).backward()
                    energy[:, v] += _row_energy(params)
                    optimizer.step()
                    bar.update(1)
    return energy.astype(np.float32)


def _row_energy(params: dict[str, torch.nn.Parameter]) -> np.ndarray:
    """``[N]`` float64 sum over parameters of each row's squared gradient norm (0 without a gradient)."""
    total = None
    for p in params.values():
        if p.grad is None:
            continue
        e = p.grad.detach().reshape(p.shape[0], -1).double().pow(2).sum(dim=1)
        total = e if total is None else total + e
    n = next(iter(params.values())).shape[0]
    return np.zeros(n) if total is None else total.cpu().numpy()


def poison_tags(model: StealthSplatModel) -> np.ndarray:
    """``[N]`` bool ground truth: which Gaussians the attack injected (``gauss_params["poison"]``)."""
    return (model.gauss_params[POISON_TAG].detach() > 0.5).cpu().numpy()
