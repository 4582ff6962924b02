"""The 3DGS model files stealth-ns reads and writes, told apart by their suffix and, for ``.ply``, by
their header (a compressed PLY has a ``chunk`` element):

================  =====================  ========================================================
format            file                   module (layout, what it loses)
================  =====================  ========================================================
ply               ``.ply``               :mod:`~stealth_ns.gaussians.ply`: float32, lossless
compressed-ply    ``.ply`` (by custom    :mod:`~stealth_ns.gaussians.compressed_ply`: PlayCanvas
                  ``.compressed.ply``)   SuperSplat / splat-transform, quantised in chunks
splat             ``.splat``             :mod:`~stealth_ns.gaussians.splat_file`: antimatter15's
                                         32-byte rows, no SH above degree 0
spz               ``.spz``               :mod:`~stealth_ns.gaussians.spz`: Niantic's, versions 2-3
================  =====================  ========================================================

Every reader returns a :class:`~stealth_ns.gaussians.ply.GaussianCloud` in the standard PLY's
conventions and frame (the SPZ reader turns its RUB frame into the PLY's); the writers keep the rows'
order, so row ``i`` of what is written is row ``i`` of the cloud. A few broken rows (a NaN or infinite
value, a zero rotation) are left out on reading, the others in their order, and said in the cloud's
``left_out`` (:mod:`~stealth_ns.gaussians.broken_rows`). Every reading problem is one
:class:`~stealth_ns.foundation.errors.StealthNSError` line naming the file.
"""

from __future__ import annotations

from pathlib import Path

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.gaussians.compressed_ply import is_compressed_ply, read_compressed_ply, write_compressed_ply
from stealth_ns.gaussians.ply import GaussianCloud, read_gaussian_ply, write_gaussian_ply
from stealth_ns.gaussians.splat_file import read_splat, write_splat
from stealth_ns.gaussians.spz import read_spz, write_spz

#: The suffixes of the model files (lower case).
MODEL_SUFFIXES: tuple[str, ...] = (".ply", ".splat", ".spz")
#: Each format's file-name ending, as :func:`model_file_name` gives it.
FORMAT_ENDINGS: dict[str, str] = {
    "ply": ".ply",
    "compressed-ply": ".compressed.ply",
    "splat": ".splat",
    "spz": ".spz",
}


def is_model_file(path: Path) -> bool:
    """Whether ``path`` has the suffix of a model file (it is not opened)."""
    return Path(path).suffix.lower() in MODEL_SUFFIXES


def model_format(path: Path) -> str:
    """The format of the model file at ``path``, a key of :data:`FORMAT_ENDINGS` (a ``.ply`` whose
    header cannot be read counts as a standard PLY: its reader says what is wrong with it)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".ply":
        return "compressed-ply" if is_compressed_ply(path) else "ply"
    if suffix in (".splat", ".spz"):
        return suffix[1:]
    raise StealthNSError(
        f"{path} is not a model file stealth-ns reads (a {', '.join(MODEL_SUFFIXES)} file: "
        "docs/design/scan.md)"
    )


def read_model_file(path: Path) -> GaussianCloud:
    """Read the model file at ``path`` in its format (:func:`model_format`)."""
    readers = {
        "ply": read_gaussian_ply,
        "compressed-ply": read_compressed_ply,
        "splat": read_splat,
        "spz": read_spz,
    }
    return readers[model_format(path)](Path(path))


def write_model_file(path: Path, cloud: GaussianCloud, like: Path, comment: str = "stealth-ns") -> None:
    """Write ``cloud`` to ``path`` in the format of the model file ``like`` (``path``'s own name does
    not matter: it may be a temporary one); ``comment`` goes into the header of the PLY formats."""
    form = model_format(like)
    if form == "ply":
        write_gaussian_ply(path, cloud, comment=comment)
    elif form == "compressed-ply":
        write_compressed_ply(path, cloud, comment=comment)
    elif form == "splat":
        write_splat(path, cloud)
    else:
        write_spz(path, cloud)


def model_file_name(stem: str, like: Path) -> str:
    """``stem`` with the ending of ``like``'s format, e.g. ``cleaned.compressed.ply`` or ``cleaned.spz``."""
    return stem + FORMAT_ENDINGS[model_format(like)]
