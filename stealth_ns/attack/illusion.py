"""Illusory objects ``O_ILL``: built-in cut-outs, loading, placement and compositing.

Paper section 3.1: the poisoned training image is ``I_ILL``, the combination of the clean image of the
poisoned view and the illusory object. As in the authors' code the object is an RGBA cut-out
alpha-composited onto the image at a fixed place, and its mask is ``alpha > 0.5`` (they use
``alpha > 128 / 255``).

Built-in illusions are cut out of images that ship inside the scikit-image wheel
(``skimage/data/*.png``), read from disk directly, never through ``skimage.data``'s downloader: nothing
here touches the network.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np
import torch
from scipy import ndimage
from skimage import color, filters, morphology
from skimage.transform import resize

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.images.io import read_image, split_alpha, to_float32

__all__ = [
    "BUILTIN_ILLUSIONS",
    "Illusion",
    "builtin_illusion",
    "composite",
    "load_illusion",
    "place_illusion",
]

ImageT = TypeVar("ImageT", np.ndarray, torch.Tensor)


@dataclass(frozen=True, eq=False)
class Illusion:
    """An RGBA object cut-out.

    Attributes:
        rgb: ``[h, w, 3]`` float32 colours in ``[0, 1]`` (not premultiplied).
        alpha: ``[h, w]`` float32 opacity in ``[0, 1]`` (soft edges allowed).
        name: short identifier (built-in name or file stem).
    """

    rgb: np.ndarray
    alpha: np.ndarray
    name: str

    def __post_init__(self) -> None:
        rgb = np.asarray(self.rgb, dtype=np.float32)
        alpha = np.asarray(self.alpha, dtype=np.float32)
        if rgb.ndim != 3 or rgb.shape[2] != 3:
            raise ValueError(f"Illusion.rgb must be [h, w, 3], got {rgb.shape}")
        if alpha.shape != rgb.shape[:2]:
            raise ValueError(f"Illusion.alpha must be [h, w] = {rgb.shape[:2]}, got {alpha.shape}")
        object.__setattr__(self, "rgb", rgb)
        object.__setattr__(self, "alpha", alpha)

    @property
    def mask(self) -> np.ndarray:
        """``[h, w]`` bool, ``alpha > 0.5``."""
        return self.alpha > 0.5

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` in pixels."""
        return int(self.rgb.shape[1]), int(self.rgb.shape[0])


# --------------------------------------------------------------------------------------------- built-ins

_SKIMAGE_DATA = Path(__import__("skimage").__file__).parent / "data"


def _read_bundled(filename: str) -> np.ndarray:
    """Read an image file shipped inside the scikit-image wheel (no fetcher, no network), as stored."""
    path = _SKIMAGE_DATA / filename
    if not path.is_file():
        raise StealthNSError(f"built-in illusion source {path} is missing from the scikit-image install")
    return read_image(path, "built-in illusion source")


def _largest_component(mask: np.ndarray) -> np.ndarray:
    labels, n = ndimage.label(mask)
    if n == 0:
        return mask.astype(bool)
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    return labels == int(sizes.argmax())


def _finish(
    rgb: np.ndarray, mask: np.ndarray, name: str, feather: float = 0.8, alpha: np.ndarray | None = None
) -> Illusion:
    """Crop to the mask's bounding box (+2 px), feather the alpha, and spread object colours outward.

    ``alpha`` (full-size, optional) replaces the feathered mask as the opacity. The colours outside the mask
    are replaced with the nearest object colour so that resizing and soft alpha never mix in the source
    photo's background.
    """
    mask = mask.astype(bool)
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    r0, r1 = max(rows[0] - 2, 0), min(rows[-1] + 3, mask.shape[0])
    c0, c1 = max(cols[0] - 2, 0), min(cols[-1] + 3, mask.shape[1])
    mask = mask[r0:r1, c0:c1]
    rgb = to_float32(rgb[r0:r1, c0:c1])
    _, (ii, jj) = ndimage.distance_transform_edt(~mask, return_indices=True)
    rgb = np.clip(rgb[ii, jj], 0, 1).astype(np.float32)
    if alpha is not None:
        alpha = alpha[r0:r1, c0:c1]
    elif feather > 0:
        alpha = ndimage.gaussian_filter(mask.astype(np.float32), sigma=feather)
    else:
        alpha = mask
    alpha = np.clip(alpha, 0, 1).astype(np.float32)
    rgb.setflags(write=False)
    alpha.setflags(write=False)
    return Illusion(rgb=rgb, alpha=alpha, name=name)


def _make_horse() -> Illusion:
    """The ``horse`` silhouette (anti-aliased black on white) filled with a saturated magenta-to-yellow
    gradient and a faint diagonal stripe texture; the drawing's anti-aliasing is the alpha."""
    img = to_float32(_read_bundled("horse.png")[..., :3])
    coverage = 1.0 - img.mean(axis=-1)  # 1 inside the black silhouette, anti-aliased at the edge
    h, w = coverage.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    hue = (0.83 + 0.32 * (xx / w) + 0.05 * (yy / h)) % 1.0  # magenta -> red -> orange -> yellow
    stripes = 0.5 + 0.5 * np.sin((xx + yy) * (2 * np.pi / 24.0))
    rgb = color.hsv2rgb(np.stack([hue, np.full_like(hue, 0.9), 0.78 + 0.22 * stripes], axis=-1))
    solid = _largest_component(coverage > 0.5)
    mask = ndimage.binary_fill_holes(solid)
    alpha = np.where(ndimage.binary_dilation(mask, iterations=2), coverage, 0.0)
    alpha[mask & ~solid] = 1.0  # pin-holes of the anti-aliased drawing
    return _finish(rgb, mask, "horse", alpha=alpha)


def _make_coffee() -> Illusion:
    """The ``coffee`` photo's cup, saucer and spoon, segmented from the wooden table.

    The red glazed saucer is the largest very saturated red region (HSV saturation > 0.85, hue within
    0.05 of red); the cup is the white region that overlaps the saucer's convex hull; the union is
    closed, hole-filled, opened and reduced to its largest connected component.
    """
    img = _read_bundled("coffee.png")[..., :3]
    hsv = color.rgb2hsv(img)
    h, s, v = hsv[..., 0], hsv[..., 1], hsv[..., 2]
    red = (s > 0.85) & ((h < 0.05) | (h > 0.95))
    saucer = _largest_component(ndimage.binary_opening(red, structure=morphology.disk(2)))
    saucer = ndimage.binary_fill_holes(ndimage.binary_closing(saucer, structure=morphology.disk(6)))
    saucer = _largest_component(ndimage.binary_opening(saucer, structure=morphology.disk(4)))
    hull = morphology.convex_hull_image(saucer)
    white = (s < 0.45) & (v > 0.55)
    labels, _ = ndimage.label(white | hull)
    obj = labels == int(np.bincount(labels[hull]).argmax())
    obj = ndimage.binary_fill_holes(ndimage.binary_closing(obj, structure=morphology.disk(5)))
    obj = _largest_component(ndimage.binary_opening(obj, structure=morphology.disk(5)))
    obj = ndimage.binary_erosion(obj, iterations=1)
    return _finish(img, obj, "coffee")


def _make_logo() -> Illusion:
    """The scikit-image logo disc (green/orange snake) cut from its white background.

    Non-white pixels, closed to bridge the white S-curve, hole-filled, largest component."""
    img = _read_bundled("logo.png")[..., :3]
    ink = img.astype(np.float32).min(axis=-1) < 235
    disc = ndimage.binary_closing(ink, structure=morphology.disk(6))
    disc = _largest_component(ndimage.binary_fill_holes(disc))
    disc = ndimage.binary_erosion(disc, iterations=1)
    return _finish(img, disc, "logo")


def _make_coin() -> Illusion:
    """One ancient coin (the bottom-left Athena head) from ``coins``, Otsu-segmented in its neighbourhood
    and tinted gold."""
    raw = _read_bundled("coins.png")[225:296, 10:83]
    crop = raw.astype(np.float32)  # Otsu on the 0-255 grey levels
    fg = crop > filters.threshold_otsu(crop)
    fg = ndimage.binary_closing(fg, structure=morphology.disk(2))
    fg = _largest_component(ndimage.binary_fill_holes(fg))
    fg = ndimage.binary_opening(fg, structure=morphology.disk(2))
    g = to_float32(raw)
    lo, hi = np.percentile(g[fg], [2, 98])
    g = np.clip((g - lo) / max(hi - lo, 1e-6), 0, 1)[..., None]
    dark, light = np.array([0.45, 0.25, 0.02]), np.array([1.0, 0.88, 0.35])
    rgb = dark + (light - dark) * g
    return _finish(rgb, fg, "coin")


# Scribble seeds (row, col) on the 512x512 ``astronaut`` photo: the person (hair, face, collar, suit,
# mission patch, the helmet she holds) and the background (flag, wall, shuttle model, table).
_ASTRONAUT_FG = (
    (40, 225), (60, 180), (60, 280), (110, 225), (200, 220), (175, 140), (240, 300), (330, 100), (300, 330),
    (420, 80), (480, 200), (400, 250), (385, 170), (430, 400), (480, 330), (400, 470), (490, 150),
)  # fmt: skip
_ASTRONAUT_BG = (
    (360, 4), (430, 4), (500, 6), (60, 30), (200, 40), (250, 10), (30, 100), (120, 110), (150, 330),
    (60, 330), (230, 330), (100, 410), (200, 400), (60, 460), (300, 450), (320, 400), (20, 500), (10, 10),
    (10, 250),
)  # fmt: skip


def _make_astronaut() -> Illusion:
    """The astronaut (Eileen Collins, in her orange suit, holding her helmet) from the ``astronaut``
    photo, segmented with a seeded random walker (on CIE Lab at half resolution) from fixed scribbles,
    then reduced to the largest component with holes filled. It is a bust: it touches the bottom edge."""
    import warnings

    from skimage import segmentation

    img = _read_bundled("astronaut.png")[..., :3]
    small = img[::2, ::2].astype(np.float64) / 255.0  # float64: the Lab segmentation was tuned on it
    lab = color.rgb2lab(small) / np.array([100.0, 128.0, 128.0])
    seeds = np.zeros(small.shape[:2], dtype=np.int32)
    for label, points in ((1, _ASTRONAUT_FG), (2, _ASTRONAUT_BG)):
        for r, c in points:
            seeds[max(r // 2 - 2, 0) : r // 2 + 3, max(c // 2 - 2, 0) : c // 2 + 3] = label
    with warnings.catch_warnings():  # "probability range outside [0, 1]" at tol=1e-3: harmless here
        warnings.simplefilter("ignore", UserWarning)
        seg = segmentation.random_walker(lab, seeds, beta=2000, mode="cg_j", tol=1e-3, channel_axis=-1)
    person = resize((seg == 1).astype(np.float32), img.shape[:2], order=1) > 0.5
    person = ndimage.binary_fill_holes(_largest_component(person))
    person = _largest_component(ndimage.binary_opening(person, structure=morphology.disk(2)))
    return _finish(img, person, "astronaut")


_BUILDERS = {
    "astronaut": _make_astronaut,
    "horse": _make_horse,
    "coffee": _make_coffee,
    "logo": _make_logo,
    "coin": _make_coin,
}

#: Names accepted by :func:`builtin_illusion`.
BUILTIN_ILLUSIONS: tuple[str, ...] = tuple(_BUILDERS)


@functools.cache  # = lru_cache(maxsize=None)
def builtin_illusion(name: str) -> Illusion:
    """A built-in illusory object (cached; its arrays are read-only -- copy before editing).

    * ``"astronaut"``: the astronaut in her orange suit holding her helmet (segmented photo, a bust).
    * ``"horse"``: the horse silhouette, filled with a bright magenta-to-yellow striped gradient.
    * ``"coffee"``: a red espresso cup on its saucer, with spoon (segmented photo).
    * ``"logo"``: the scikit-image logo disc (green and orange snake).
    * ``"coin"``: an ancient coin, tinted gold.

    Raises:
        StealthNSError: unknown name.
    """
    try:
        builder = _BUILDERS[name]
    except KeyError:
        raise StealthNSError(
            f"unknown built-in illusion {name!r}: choose one of {', '.join(BUILTIN_ILLUSIONS)} "
            "or give an image file"
        ) from None
    return builder()


# ------------------------------------------------------------------------------------------- file I/O


def _read_checked(path: Path, what: str) -> np.ndarray:
    """:func:`~stealth_ns.images.io.read_image`, refusing what is not one 2-D grey / grey+alpha / RGB /
    RGBA image of numbers."""
    arr = read_image(path, what)
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] not in (1, 2, 3, 4)):
        raise StealthNSError(f"{what} {path} has unsupported shape {arr.shape} (expected a single 2-D image)")
    if arr.dtype.kind not in "biuf":
        raise StealthNSError(f"{what} {path} has unsupported pixel type {arr.dtype}")
    return arr


def load_illusion(image_path: str | Path, mask_path: str | Path | None = None) -> Illusion:
    """Load an illusion from an RGBA image (alpha = opacity) or an RGB image plus a mask image.

    * RGBA / grey+alpha image without ``mask_path``: the alpha channel is the illusion's alpha.
    * With ``mask_path`` (wins over an alpha channel): the mask, greyscale / RGB (max over channels) /
      RGBA (its alpha if not fully opaque, else its colour) / bool, normalised to [0, 1] by its dtype's
      range, is the alpha; the mask is ``alpha > 0.5``.
    * Greyscale images are replicated to RGB. Pixel values are scaled by their dtype's range
      (:func:`~stealth_ns.images.io.to_float32`: uint8 by 255, uint16 by 65535; floats are taken as
      [0, 1] and clipped).

    Raises:
        StealthNSError: file missing or not readable as an image; RGB image without mask and without an
            alpha channel; mask size different from the image size; empty mask (no pixel > 0.5), including
            a fully transparent RGBA image.
    """
    image_path = Path(image_path)
    arr = _read_checked(image_path, "illusion image")
    rgb, image_alpha = split_alpha(arr)
    if mask_path is not None:
        alpha = _mask_alpha(Path(mask_path), image_path, arr.shape[:2])
    elif image_alpha is not None:
        alpha = image_alpha
        if not np.any(alpha > 0.5):
            raise StealthNSError(f"illusion image {image_path} is fully transparent (no alpha above 0.5)")
    else:
        raise StealthNSError(
            f"illusion image {image_path} has no alpha channel: give an RGBA PNG or also a mask image"
        )
    return Illusion(rgb=rgb, alpha=alpha, name=image_path.stem)


def _mask_alpha(mask_path: Path, image_path: Path, image_hw: tuple[int, int]) -> np.ndarray:
    """The opacity ``[H, W]`` in [0, 1] a mask file gives (see :func:`load_illusion`)."""
    marr = _read_checked(mask_path, "illusion mask")
    if marr.shape[:2] != image_hw:
        raise StealthNSError(
            f"illusion mask {mask_path} is {marr.shape[1]}x{marr.shape[0]} px but the image "
            f"{image_path.name} is {image_hw[1]}x{image_hw[0]} px"
        )
    mrgb, malpha = split_alpha(marr)
    alpha = malpha if malpha is not None and malpha.min() < 1.0 else mrgb.max(axis=2)
    if not np.any(alpha > 0.5):
        raise StealthNSError(f"illusion mask {mask_path} is empty (no pixel above 0.5)")
    return alpha


# ---------------------------------------------------------------------------------- placement / compositing


def place_illusion(
    illusion: Illusion,
    image_hw: tuple[int, int],
    center: tuple[float, float] = (0.5, 0.5),
    scale: float = 0.4,
) -> tuple[np.ndarray, np.ndarray]:
    """Resize an illusion and paste it into an image-sized transparent canvas.

    The illusion is resized (``skimage.transform.resize``, bilinear, anti-aliased, on premultiplied
    colours so no background colour bleeds in) to a height of ``round(scale * H)`` pixels, keeping its
    aspect ratio, and centred at ``(center[0] * W, center[1] * H)``; if that would cross the image border
    the box is shifted inwards so the whole illusion stays visible.

    Args:
        illusion: the object cut-out.
        image_hw: ``(H, W)`` of the target image in pixels.
        center: ``(x, y)`` centre as fractions of the image width and height, each in ``[0, 1]``.
        scale: illusion height as a fraction of the image height (> 0).

    Returns:
        ``(rgb [H, W, 3], alpha [H, W])`` float32 in ``[0, 1]``; zero outside the illusion.

    Raises:
        StealthNSError: ``scale <= 0``, ``center`` outside ``[0, 1]``, the resized illusion larger than the
            image, or its mask empty after resizing (scale too small).
    """
    H, W = (int(v) for v in image_hw)
    if H < 1 or W < 1:
        raise StealthNSError(f"image size {W}x{H} px is empty")
    if not (math.isfinite(scale) and scale > 0):
        raise StealthNSError(f"illusion scale must be > 0 (fraction of the image height), got {scale}")
    cx, cy = (float(c) for c in center)
    if not (0.0 <= cx <= 1.0 and 0.0 <= cy <= 1.0):
        raise StealthNSError(f"illusion centre ({cx}, {cy}) is outside the image: both must be in [0, 1]")
    ih, iw = illusion.alpha.shape
    h = max(1, int(round(scale * H)))
    w = max(1, int(round(h * iw / ih)))
    if h > H or w > W:
        raise StealthNSError(f"illusion of {w}x{h} px does not fit in the {W}x{H} image at scale {scale}")
    alpha = np.clip(resize(illusion.alpha, (h, w), order=1, anti_aliasing=True, mode="edge"), 0.0, 1.0)
    premult = resize(
        illusion.rgb * illusion.alpha[..., None], (h, w), order=1, anti_aliasing=True, mode="edge"
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        rgb = np.where(alpha[..., None] > 1e-6, premult / alpha[..., None], 0.0)
    rgb = np.clip(rgb, 0.0, 1.0)
    if not np.any(alpha > 0.5):
        raise StealthNSError(
            f"illusion mask is empty at scale {scale} ({w}x{h} px in a {W}x{H} image): increase the scale"
        )
    top = min(max(int(round(cy * H - h / 2.0)), 0), H - h)
    left = min(max(int(round(cx * W - w / 2.0)), 0), W - w)
    out_rgb = np.zeros((H, W, 3), dtype=np.float32)
    out_alpha = np.zeros((H, W), dtype=np.float32)
    out_rgb[top : top + h, left : left + w] = rgb
    out_alpha[top : top + h, left : left + w] = alpha
    return out_rgb, out_alpha


def composite(image: ImageT, rgb: np.ndarray | torch.Tensor, alpha: np.ndarray | torch.Tensor) -> ImageT:
    """Alpha-composite the placed illusion over an image: ``I_ILL = alpha * rgb + (1 - alpha) * I``.

    Args:
        image: ``[H, W, 3]`` uint8 (0..255) or float in [0, 1]; numpy array or torch tensor.
        rgb: ``[H, W, 3]`` illusion colours in [0, 1] (from :func:`place_illusion`).
        alpha: ``[H, W]`` illusion opacity in [0, 1].

    Returns:
        A new image of the same type, dtype, shape (and device); uint8 results are rounded to nearest.
    """
    is_numpy = not isinstance(image, torch.Tensor)
    img = torch.from_numpy(np.asarray(image)) if is_numpy else image
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image must be [H, W, 3], got {tuple(img.shape)}")
    work = torch.float64 if is_numpy else torch.promote_types(img.dtype, torch.float32)
    if img.dtype == torch.uint8:
        work = torch.float64 if is_numpy else torch.float32
    fg = torch.as_tensor(rgb, device=img.device).to(work)
    a = torch.as_tensor(alpha, device=img.device).to(work)
    if fg.shape != img.shape or a.shape != img.shape[:2]:
        raise ValueError(
            f"rgb {tuple(fg.shape)} / alpha {tuple(a.shape)} do not match the image {tuple(img.shape)}"
        )
    a = a.clamp(0, 1)[..., None]
    if img.dtype == torch.uint8:
        out = (a * fg.clamp(0, 1) * 255.0 + (1 - a) * img.to(work)).round().clamp(0, 255).to(torch.uint8)
    elif torch.is_floating_point(img):
        out = (a * fg + (1 - a) * img.to(work)).to(img.dtype)
    else:
        raise ValueError(f"image must be uint8 or floating point, got {img.dtype}")
    return out.numpy() if is_numpy else out  # type: ignore[return-value]
