"""The input-filter defence: denoise every training image before the model sees it.

DefenseSplat low-pass / wavelet-filters the training images so that high-frequency poison (and
here also the attack's view-consistency noise) does not reach the model; RemedyGS purifies them
with a learned model (not available here). The filters are scikit-image's:

* ``wavelet``: ``skimage.restoration.denoise_wavelet`` per channel, BayesShrink soft thresholding
  with the noise level estimated from each image (``rescale_sigma=True``), db1, 3 levels;
* ``gaussian``: ``skimage.filters.gaussian`` low-pass, ``sigma`` pixels.

The filter runs on the image the trainer receives (after the attack replaced the poisoned view and
noised the innocent ones): the defender filters the data it was given. With the stealth-splat
methods it is ``--pipeline.datamanager.input-filter {none,wavelet,gaussian}``; ``stealth-ns defend``
retrains a poisoned run with it (:func:`filtered_config`).
"""

from __future__ import annotations

import numpy as np


def filter_image(image: np.ndarray, kind: str, sigma: float = 1.0) -> np.ndarray:
    """Filter one image.

    Args:
        image: ``[H, W, C]`` uint8 (0..255) or float in [0, 1]; an alpha channel (C = 4) is kept as is.
        kind: "wavelet" or "gaussian" (see the module docstring); "none" returns a copy.
        sigma: the gaussian filter's standard deviation in pixels.

    Returns:
        The filtered image, same shape and dtype (uint8 rounded to nearest).
    """
    from skimage.filters import gaussian
    from skimage.restoration import denoise_wavelet

    if kind == "none":
        return image.copy()
    is_uint8 = image.dtype == np.uint8
    rgb = image[..., :3].astype(np.float64) / (255.0 if is_uint8 else 1.0)
    if kind == "wavelet":
        out = denoise_wavelet(
            rgb,
            wavelet="db1",
            mode="soft",
            wavelet_levels=3,
            method="BayesShrink",
            rescale_sigma=True,
            channel_axis=-1,
        )
    elif kind == "gaussian":
        out = gaussian(rgb, sigma=sigma, channel_axis=-1, preserve_range=True)
    else:
        raise ValueError(f"unknown input filter {kind!r} (wavelet, gaussian or none)")
    out = np.clip(out, 0.0, 1.0)
    out = np.round(out * 255.0).astype(np.uint8) if is_uint8 else out.astype(image.dtype)
    if image.shape[-1] == 4:
        out = np.concatenate([out, image[..., 3:]], axis=-1)
    return out
