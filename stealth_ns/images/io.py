"""Reading and writing images: one library (imageio v3) and scikit-image's dtype conversions.

Every image file stealth-ns reads or writes goes through here, so a format quirk (16-bit PNGs,
palettes, a stray alpha channel, a file that is no image) is handled once.

Files are decoded with imageio's ``pillow`` plugin only: it is what nerfstudio's data loading
uses (PIL), and imageio's automatic plugin choice would hand a file Pillow cannot identify to
PyAV, which "reads" a text file as an empty video instead of refusing it. Importing this module
does not import torch (tensors are recognised by duck typing; the two helpers for nerfstudio's cached
training images, :func:`rgb_float` and :func:`cached_format`, import it when called).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from skimage.util import img_as_ubyte

from stealth_ns.foundation.errors import StealthNSError, write_error
from stealth_ns.foundation.json_io import write_bytes_atomic

if TYPE_CHECKING:
    import torch

__all__ = [
    "ImageInfo",
    "cached_format",
    "image_info",
    "image_size",
    "read_image",
    "rgb_float",
    "encode_png",
    "save_png",
    "split_alpha",
    "to_float32",
    "to_uint8",
]

PLUGIN = "pillow"
"""The imageio plugin for every read and write (see the module docstring)."""


@dataclass(frozen=True)
class ImageInfo:
    """An image file's header (no pixels decoded): what :func:`read_image` would return."""

    width: int
    """Pixels."""
    height: int
    """Pixels."""
    channels: int
    """1 (grey), 2 (grey + alpha), 3 (RGB) or 4 (RGBA; also CMYK)."""
    dtype: np.dtype
    """Pixel type as decoded: uint8, uint16, bool (bilevel), float32, ... (a palette image: its
    palette's colours, uint8)."""


def _checked_path(path: str | Path, what: str) -> Path:
    path = Path(path)
    if not path.exists():
        raise StealthNSError(f"{what} {path} does not exist")
    if not path.is_file():
        raise StealthNSError(f"{what} {path} is not a file")
    return path


def _unreadable(path: Path, what: str, exc: Exception) -> StealthNSError:
    """One line: "not an image" for a file Pillow does not recognise, else the first line of the
    decoder's message without the path (or the exception's type)."""
    from imageio.core.request import InitializationError

    if isinstance(exc.__cause__, InitializationError):
        reason = "not a format Pillow can read"
    else:
        lines = str(exc).replace(str(path), "").strip(" :.\n").splitlines()
        reason = lines[0].strip(" :.") if lines and lines[0].strip(" :.") else type(exc).__name__
    return StealthNSError(f"{what} {path} cannot be read as an image ({reason})")


def read_image(path: str | Path, what: str = "image") -> np.ndarray:
    """The (first) image in ``path`` as stored: ``[H, W]`` or ``[H, W, C]``, its own dtype.

    uint8 for 8-bit files, uint16 for 16-bit PNGs, bool for bilevel images; palette images come
    as their palette's colours.

    Args:
        path: the file.
        what: how error messages name the file (``"illusion mask"``, ``"frame 3: image"``).

    Raises:
        StealthNSError: the file is missing, is a folder, or is not a readable (or is a truncated)
            image; one line naming the file.
    """
    import imageio.v3 as iio

    path = _checked_path(path, what)
    try:
        image = np.asarray(iio.imread(path, plugin=PLUGIN, index=0))
    except Exception as exc:  # Pillow raises many types (UnidentifiedImageError, OSError, SyntaxError, ...)
        raise _unreadable(path, what, exc) from None
    if image.size == 0:
        raise StealthNSError(f"{what} {path} cannot be read as an image (it holds no pixels)")
    return image


def image_info(path: str | Path, what: str = "image") -> ImageInfo:
    """The header of the image file ``path`` (reads no pixel data; fast for large images).

    Raises:
        StealthNSError: as :func:`read_image`, for a missing file or one that is no image.
    """
    import imageio.v3 as iio

    path = _checked_path(path, what)
    try:
        props = iio.improps(path, plugin=PLUGIN, index=0)  # not immeta: it decodes a PNG for its EXIF
    except Exception as exc:  # as in read_image
        raise _unreadable(path, what, exc) from None
    height, width = (int(v) for v in props.shape[:2])
    channels = int(props.shape[2]) if len(props.shape) > 2 else 1
    return ImageInfo(width, height, channels, np.dtype(props.dtype))


def image_size(path: str | Path, what: str = "image") -> tuple[int, int]:
    """``(width, height)`` in pixels of the image file ``path``, from its header."""
    info = image_info(path, what)
    return info.width, info.height


def to_float32(image: np.ndarray | torch.Tensor) -> np.ndarray:
    """Any image as float32 in [0, 1]: integers are divided by their dtype's maximum (uint8 by 255,
    uint16 by 65535), bool gives 0 / 1, floats are only clipped (NaN -> 0).

    A division, not ``img_as_float32``'s multiplication by ``1 / max``: the two differ in the last bit
    for some values, and the illusion targets (so every published V-illusory figure) were made with it.
    """
    arr = _numpy(image)
    if arr.dtype.kind == "f":
        return np.clip(np.nan_to_num(arr.astype(np.float32)), 0.0, 1.0)
    if arr.dtype.kind == "b":
        return arr.astype(np.float32)
    out = arr.astype(np.float32) / np.float32(np.iinfo(arr.dtype).max)
    return np.clip(out, 0.0, 1.0) if arr.dtype.kind == "i" else out  # signed: negative values -> 0


def to_uint8(image: np.ndarray | torch.Tensor) -> np.ndarray:
    """Any image as uint8 (``img_as_ubyte``): uint8 as is, bool as 0 / 255, other integers rescaled,
    floats clipped to [0, 1] (NaN -> 0), scaled by 255 and rounded to nearest, ties to even.

    Ties to even, not up (as ``img_as_ubyte``); on generated scenes the only exact ties are at 127.5
    (0.5), where both rules give 128 (docs/design/determinism.md).
    """
    arr = _numpy(image)
    if arr.dtype.kind == "f":
        arr = np.clip(np.nan_to_num(arr.astype(np.float64)), 0.0, 1.0)
    return img_as_ubyte(arr)


def rgb_float(image: torch.Tensor) -> torch.Tensor:
    """[H, W, 3 or 4] uint8 or float cached image -> [H, W, 3] float32 in [0, 1], on the CPU."""
    import torch

    return torch.from_numpy(to_float32(image[..., :3]))


def cached_format(rgb: torch.Tensor, clean: torch.Tensor, opaque: torch.Tensor | None = None) -> torch.Tensor:
    """A float [H, W, 3] training image in the cache's dtype/channels of ``clean``: images with alpha
    (blender) keep their alpha, made opaque where ``opaque`` ([H, W] bool) is set."""
    import torch

    if clean.dtype == torch.uint8:
        rgb = (rgb * 255.0).round().clamp(0, 255).to(torch.uint8)
    if clean.shape[-1] == 4:
        a = clean[..., 3:].clone()
        if opaque is not None:
            a[opaque] = 255 if clean.dtype == torch.uint8 else 1.0
        rgb = torch.cat([rgb, a], -1)
    return rgb


def split_alpha(image: np.ndarray | torch.Tensor) -> tuple[np.ndarray, np.ndarray | None]:
    """An image's colours and opacity, as float32 in [0, 1] (see :func:`to_float32`).

    Args:
        image: ``[H, W]`` grey, ``[H, W, 1]``, ``[H, W, 2]`` grey + alpha, ``[H, W, 3]`` RGB or
            ``[H, W, 4]`` RGBA.

    Returns:
        ``(rgb [H, W, 3], alpha [H, W])``: grey is repeated into the three channels; ``alpha`` is
        None for an image without an alpha channel. Colours are straight (not premultiplied).
    """
    unit = to_float32(image)
    if unit.ndim == 2:
        unit = unit[..., None]
    if unit.ndim != 3 or unit.shape[2] not in (1, 2, 3, 4):
        raise ValueError(f"split_alpha expects [H, W], [H, W, 1|2|3|4], got {unit.shape}")
    channels = unit.shape[2]
    rgb = np.repeat(unit[..., :1], 3, axis=2) if channels <= 2 else unit[..., :3]
    alpha = unit[..., -1] if channels in (2, 4) else None
    return rgb, alpha


def save_png(path: str | Path, image: np.ndarray | torch.Tensor) -> Path:
    """Write an 8-bit PNG (creating parent directories), deterministically: no metadata, no
    timestamp, so the same pixels give the same bytes. Encoded in memory and written whole or not at
    all (:func:`~stealth_ns.foundation.json_io.write_bytes_atomic`): a full disk leaves no truncated picture,
    and is a one-line StealthNSError ``cannot write PATH: No space left on device``.

    Args:
        path: output file.
        image: ``[H, W]``, ``[H, W, 1]``, ``[H, W, 3]`` or ``[H, W, 4]``; bool (-> 0/255), uint8 (as is)
            or float in [0, 1] (see :func:`to_uint8`). Torch tensors are moved to the CPU.

    Returns:
        The path written.
    """
    import imageio.v3 as iio

    data = iio.imwrite("<bytes>", _png_pixels(image, "save_png"), plugin=PLUGIN, extension=".png")
    path = Path(path)
    _make_parent(path)
    write_bytes_atomic(path, data)
    return path


def encode_png(image: np.ndarray | torch.Tensor, compress_level: int = 6) -> bytes:
    """The 8-bit PNG file :func:`save_png` writes, in memory, at zlib level ``compress_level`` (0-9:
    faster to larger files; Pillow's default is 6). The pixels do not depend on the level."""
    import imageio.v3 as iio

    return iio.imwrite("<bytes>", _png_pixels(image, "encode_png"), plugin=PLUGIN, extension=".png",
                       compress_level=int(compress_level))  # fmt: skip


def _png_pixels(image: np.ndarray | torch.Tensor, caller: str) -> np.ndarray:
    """``image`` as the contiguous uint8 ``[H, W]``, ``[H, W, 3]`` or ``[H, W, 4]`` a PNG holds."""
    arr = _numpy(image)
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] not in (1, 3, 4)):
        raise ValueError(f"{caller} expects [H, W], [H, W, 1], [H, W, 3] or [H, W, 4], got {arr.shape}")
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]
    return np.ascontiguousarray(to_uint8(arr))


def save_image(path: str | Path, image: np.ndarray | torch.Tensor) -> Path:
    """Write an 8-bit image in the format of ``path``'s extension: PNG as :func:`save_png`, JPEG at
    quality 100 (still lossy: callers that need exact pixels re-read the file), other formats as the
    plugin writes them; whole or not at all, as :func:`save_png`."""
    import imageio.v3 as iio

    path = Path(path)
    if path.suffix.lower() == ".png":
        return save_png(path, image)
    arr = np.ascontiguousarray(to_uint8(_numpy(image)))
    _make_parent(path)
    options = {"quality": 100} if path.suffix.lower() in (".jpg", ".jpeg") else {}
    try:  # in memory first: the file is then written whole or not at all
        data = iio.imwrite("<bytes>", arr, plugin=PLUGIN, extension=path.suffix, **options)
    except Exception as exc:  # Pillow raises many types for formats it cannot write
        raise StealthNSError(f"cannot write {path}: {type(exc).__name__}: {exc}") from None
    write_bytes_atomic(path, data)
    return path


def _make_parent(path: Path) -> None:
    """Create ``path``'s folder; a one-line StealthNSError when that fails (read-only, full)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise write_error(path, err) from None


def _numpy(image: np.ndarray | torch.Tensor) -> np.ndarray:
    """A numpy view of ``image``; a torch tensor (recognised without importing torch) is detached
    and copied to the CPU."""
    if hasattr(image, "detach") and hasattr(image, "cpu"):
        return image.detach().cpu().numpy()
    return np.asarray(image)
