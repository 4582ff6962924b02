"""Whether a dataset's RGB images were composited on a uniform white or black background.

Object captures exported as RGB (a COLMAP or nerfstudio-data dataset, not Blender's RGBA) often carry the
object on pure white or black. Trained under splatfacto's default random background, the model must
paint that colour with Gaussians, and the held-out PSNR suffers (measured: docs/design/cpu_rasterizer.md,
"Object captures"); ``--pipeline.model.background-color`` set to that colour avoids it. ns-train says
so when it starts.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

#: Border pixels of an image within this many 8-bit levels of pure white (or black), every channel.
TOLERANCE = 3
#: An image has a uniform background when at least this share of its border pixels is that colour ...
BORDER_SHARE = 0.9
#: ... and the dataset when at least this share of the images looked at has the same one.
IMAGE_SHARE = 0.8
BORDER = 2  # pixels of each edge


def border_pixels(image: np.ndarray) -> np.ndarray:
    """The outer :data:`BORDER` pixels of each edge of ``image`` (uint8 [H, W, C]) -> [P, C]."""
    h, w = image.shape[:2]
    b = max(1, min(BORDER, h // 4, w // 4))
    mask = np.zeros((h, w), dtype=bool)
    mask[:b], mask[-b:], mask[:, :b], mask[:, -b:] = True, True, True, True
    return image[mask]


def uniform_background(images: Iterable[np.ndarray]) -> tuple[str, float] | None:
    """``("white" | "black", share of the images)`` when the RGB ``images`` (uint8 [H, W, 3]) show a
    uniform white or black border (see the module constants), else None; images with an alpha channel
    are left out (the model composites those itself)."""
    votes = {"white": 0, "black": 0}
    n = 0
    for image in images:
        if image.ndim != 3 or image.shape[-1] != 3:
            continue
        n += 1
        border = border_pixels(np.asarray(image)).astype(np.int16)
        for colour, level in (("white", 255), ("black", 0)):
            if (np.abs(border - level) <= TOLERANCE).all(axis=-1).mean() >= BORDER_SHARE:
                votes[colour] += 1
    if n == 0:
        return None
    colour = max(votes, key=votes.__getitem__)
    share = votes[colour] / n
    return (colour, share) if share >= IMAGE_SHARE else None
