"""View consistency disruption (paper section 3.4): decaying Gaussian noise on the innocent views.

Every innocent training image ``I_k`` is replaced, at training step ``t``, by ``clip(I_k + eta)`` with
``eta ~ N(0, sigma_t^2)`` i.i.d. per pixel and channel; the poisoned view stays clean. ``sigma_t`` is on
the 0-255 intensity scale (the paper's ``sigma_0`` is 30 or 100; linear decay with ``sigma_0 = 100`` is
its default) and decays over the ``T`` training steps:

    linear:  sigma_0 * (1 - t / T)
    cosine:  sigma_0 * cos(pi t / (2 T))
    sqrt:    sigma_0 * sqrt(1 - t / T)
    constant: sigma_0 (ablation)

Importing this module does not import torch (only :func:`noisy_image` needs it), so that
:mod:`stealth_ns.attack.config` can take :data:`NoiseDecay` from here and stay light.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Literal, TypeVar, get_args

import numpy as np

from stealth_ns.attack.normal_draw import noisy_uint8, normal_deviates

if TYPE_CHECKING:
    import torch

__all__ = ["NOISE_DECAYS", "NoiseDecay", "noise_sigma", "noise_seed", "noisy_image"]

NoiseDecay = Literal["linear", "cosine", "sqrt", "constant"]
"""How the noise strength decays over training (``AttackConfig.noise_decay``)."""
NOISE_DECAYS: tuple[str, ...] = get_args(NoiseDecay)

ImageT = TypeVar("ImageT", "torch.Tensor", np.ndarray)


def noise_sigma(step: int, total_steps: int, sigma0: float, decay: NoiseDecay = "linear") -> float:
    """Noise standard deviation ``sigma_t`` (0-255 scale) at training step ``step`` (paper eqs. 6-8).

    Args:
        step: current iteration ``t``; clamped to ``[0, total_steps]`` (so it is 0 from ``T`` on for the
            decaying schedules).
        total_steps: ``T`` > 0, the number of steps over which the noise decays (normally the training
            length).
        sigma0: initial strength ``sigma_0`` >= 0 on the 0-255 scale.
        decay: ``"linear"``, ``"cosine"``, ``"sqrt"`` or ``"constant"``.

    Returns:
        ``sigma_t`` >= 0 as a Python float (exactly 0 at ``t >= T`` except for ``"constant"``).

    Raises:
        ValueError: unknown ``decay``, ``total_steps`` not a positive integer, ``sigma0`` negative or not
            finite, ``step`` not an integer.
    """
    if decay not in NOISE_DECAYS:
        raise ValueError(f"unknown noise decay {decay!r}: expected one of {', '.join(NOISE_DECAYS)}")
    if isinstance(total_steps, bool) or int(total_steps) != total_steps or total_steps < 1:
        raise ValueError(f"total_steps must be a positive integer, got {total_steps!r}")
    if isinstance(step, bool) or int(step) != step:
        raise ValueError(f"step must be an integer, got {step!r}")
    sigma0 = float(sigma0)
    if not (math.isfinite(sigma0) and sigma0 >= 0):
        raise ValueError(f"sigma0 must be a non-negative number (0-255 scale), got {sigma0!r}")
    if decay == "constant":
        return sigma0
    t = min(max(int(step), 0), int(total_steps))
    if t == total_steps:
        return 0.0
    r = t / int(total_steps)
    if decay == "linear":
        return sigma0 * (1.0 - r)
    if decay == "cosine":
        return sigma0 * math.cos(math.pi * r / 2.0)
    return sigma0 * math.sqrt(1.0 - r)


def noise_seed(seed: int, view_index: int, step: int) -> int:
    """A 63-bit seed derived from ``(seed, view_index, step)`` with ``numpy.random.SeedSequence``.

    Distinct triples give statistically independent streams; all three must be non-negative integers.
    """
    for name, v in (("seed", seed), ("view_index", view_index), ("step", step)):
        if isinstance(v, bool) or int(v) != v or v < 0:
            raise ValueError(f"{name} must be a non-negative integer, got {v!r}")
    state = np.random.SeedSequence([int(seed), int(view_index), int(step)]).generate_state(2, dtype=np.uint32)
    return ((int(state[0]) << 32) | int(state[1])) & ((1 << 63) - 1)


def noisy_image(image: ImageT, sigma_255: float, seed: int, view_index: int, step: int) -> ImageT:
    """``clip(I + eta)``, ``eta ~ N(0, sigma^2)`` i.i.d. per pixel and channel, out of place.

    The noise is stream :func:`noise_seed` ``(seed, view_index, step)`` of
    :mod:`stealth_ns.attack.normal_draw` over the flattened image, drawn on the image's device with
    the same bits on every device, so it is reproducible for a given triple anywhere, and independent
    across views and steps.

    Args:
        image: ``[H, W, C]`` (any shape works) torch tensor or numpy array, either uint8 in 0..255 or float
            in [0, 1] (any float dtype; computed in float32 or better).
        sigma_255: standard deviation on the 0-255 scale (``sigma / 255`` is used for float images), >= 0.
        seed: experiment seed (>= 0).
        view_index: index of the training view (>= 0).
        step: training step (>= 0).

    Returns:
        A new array of the same type, dtype, shape and device: uint8 images are rounded to the nearest
        integer and clipped to 0..255, float images clipped to [0, 1]. ``sigma_255 == 0`` returns an
        unchanged copy.
    """
    import torch

    sigma = float(sigma_255)
    if not (math.isfinite(sigma) and sigma >= 0):
        raise ValueError(f"sigma_255 must be a non-negative number, got {sigma_255!r}")
    gen_seed = noise_seed(seed, view_index, step)
    is_numpy = not isinstance(image, torch.Tensor)
    img = torch.from_numpy(np.array(image, copy=True)) if is_numpy else image
    if img.dtype == torch.bool or not (img.dtype == torch.uint8 or torch.is_floating_point(img)):
        raise ValueError(f"image must be uint8 or floating point, got {img.dtype}")
    if sigma == 0:
        out = img.clone()
    elif img.dtype == torch.uint8:
        out = noisy_uint8(img, sigma, gen_seed)
    else:
        noise = normal_deviates(tuple(img.shape), gen_seed, img.device)
        work = torch.promote_types(img.dtype, torch.float32)
        out = (img.to(work) + (sigma / 255.0) * noise.to(work)).clamp_(0.0, 1.0).to(img.dtype)
    return out.numpy() if is_numpy else out  # type: ignore[return-value]
