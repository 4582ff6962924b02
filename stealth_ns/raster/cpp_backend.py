"""Compiled CPU backend of 3D Gaussian Splatting: projection + SH, tile intersection, rasterize-to-pixels.

The C++ sources (``csrc/<kernel>_cpu.cpp`` for each name in ``_KERNELS`` and their Python bindings
``csrc/bindings.cpp``) are compiled on first use
with ``torch.utils.cpp_extension.load`` (g++ + ninja, OpenMP; build times: docs/design/cpu_rasterizer.md) into
a cache directory:

* ``$STEALTH_NS_CACHE/torch_ext/<key>`` when ``STEALTH_NS_CACHE`` is set,
* ``~/.cache/stealth_ns/torch_ext/<key>`` otherwise,

where ``<key>`` hashes the sources, the compiler flags, the torch and Python versions, the CPU
model/flags, so a cache shared between machines never hands out a binary built for another CPU, and
the ``ninja`` that builds it (:func:`_ninja_program`: the venv's, else the first on ``PATH``).

Set ``STEALTH_NS_DISABLE_CPP=1`` to force the pure-PyTorch fallback: :func:`load_extension` then
returns ``None`` and :func:`compile_error` says why.

The kernels mirror gsplat 1.4.0's CUDA ``rasterize_to_pixels`` forward/backward (see the header of
the C++ file for the exact semantics), its ``isect_tiles`` + ``isect_offset_encode``, and its
projection and SH (forward and backward; ``projection.py`` is their torch reference); the same
module holds the training loss's SSIM (``stealth_ns/images/ssim.py``; pytorch_msssim is its reference), the
densification statistics (``stealth_ns/method/densification.py``; its torch code is their reference), the
background composite (``composite.py``), camera visibility counts, camera-proximity's depth ratios
(``stealth_ns/defences/scores.py``'s numpy code is the reference), the injection's ray search
(``stealth_ns/attack/ray_search.py``; its torch code is the reference) and the attack's view noise
(``stealth_ns/attack/normal_draw.py``; its numpy code is their reference).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import platform
import shutil
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from stealth_ns.foundation.step_timing import phase
from stealth_ns.raster.projection import SHCoefficients
from stealth_ns.raster.tiles import FOOTPRINT_MIN_TILES, Footprint

__all__ = [
    "EXTENSION_NAME",
    "RasterizeToPixelsCPU",
    "build_directory",
    "compile_error",
    "compile_seconds",
    "isect_tiles_cpp",
    "load_build",
    "load_extension",
    "project_gaussians_cpp",
    "rasterize_to_pixels_cpp",
    "sh_colors_cpp",
]

EXTENSION_NAME = "stealth_ns_raster_cpu"
_CSRC = Path(__file__).resolve().parent / "csrc"
# csrc/<name>_cpu.cpp + .h, bound in bindings.cpp
_KERNELS = (
    "rasterize",
    "project",
    "ssim",
    "composite",
    "densify",
    "visibility",
    "frustum",
    "ray_search",
    "noise",
)
_SOURCES = (*(_CSRC / f"{name}_cpu.cpp" for name in _KERNELS), _CSRC / "bindings.cpp")
_HEADERS = (
    *(_CSRC / f"{name}_cpu.h" for name in _KERNELS),
    _CSRC / "tensor_checks.h",
    _CSRC / "camera_views.h",
    _CSRC / "simd_width.h",
)
# -O3 without -ffast-math: fast-math would let the compiler reorder the float expressions that
# decide which (pixel, Gaussian) pairs pass the alpha >= 1/255 test, so forward and backward could
# disagree.  -ffp-contract=off for the same reason (no FMA contraction that may differ between the
# forward and backward loops); it also makes the results bitwise identical whatever the target ISA.
# -march=native (wider registers than baseline x86-64's SSE2, 4 floats a register; the speed-up is in
# docs/design/cpu_rasterizer.md) is safe because the cache key includes the CPU; if the compiler rejects it
# we retry without.
_BASE_CFLAGS = [
    "-O3",
    "-fopenmp",
    "-ffp-contract=off",
    "-fno-math-errno",
    f"-DSTEALTH_NS_FOOTPRINT_MIN_TILES={FOOTPRINT_MIN_TILES}",  # one value for the kernel and tiles.py
]
_FLAG_SETS = (["-march=native"], [])
_CFLAGS = _BASE_CFLAGS + _FLAG_SETS[0]
_LDFLAGS = ["-fopenmp"]
# Backward accumulation of per-Gaussian gradients across tiles: 0 = per-intersection records reduced
# in a fixed order (deterministic), 1 = atomics, 2 = per-thread buffers.  See docs/design/cpu_rasterizer.md.
DEFAULT_BWD_MODE = 0

_lock = threading.Lock()
_module: Any = None
_error: str | None = None
_tried = False
_compile_seconds: float | None = None


def _cpu_signature() -> str:
    """CPU model + feature flags (the binary is built with -march=native)."""
    parts = [platform.machine()]
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                key = line.split(":", 1)[0].strip()
                if key in ("model name", "flags", "Features", "CPU part") and ":" in line:
                    parts.append(line.split(":", 1)[1].strip())
                if len(parts) >= 3:
                    break
    except OSError:
        parts.append(platform.processor())
    return "|".join(parts)


def _ninja_program() -> str:
    """The ``ninja`` that builds the extension, resolved: the one beside this Python (the venv's, which
    nerfstudio requires) when there is one, else the first on ``PATH``; ``""`` if none.

    torch runs ``ninja`` by name: left to ``PATH`` it would run the venv's when the venv is activated
    and the system's when not, or none at all on a machine without a system ninja (then no kernels are
    built). Two ninja versions read each other's build logs as foreign, so alternating between them
    rebuilds every kernel each time (docs/design/training_step.md, "Two ninjas, one build directory").
    """
    beside = Path(sys.executable).parent / "ninja" if sys.executable else None  # "" when embedded
    if beside is not None and beside.is_file() and os.access(beside, os.X_OK):
        return str(beside.resolve())
    found = shutil.which("ninja")
    return os.path.realpath(found) if found else ""


@contextlib.contextmanager
def _first_on_path(program: str) -> Iterator[None]:
    """``PATH`` with ``program``'s directory first for the duration (torch runs ``ninja`` by name)."""
    if not program:
        yield
        return
    saved = os.environ.get("PATH")
    os.environ["PATH"] = os.pathsep.join(p for p in (os.path.dirname(program), saved) if p)
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop("PATH", None)
        else:
            os.environ["PATH"] = saved


def _cache_key(cflags: list[str] | None = None) -> str:
    h = hashlib.sha256()
    for path in (*_SOURCES, *_HEADERS):
        h.update(path.read_bytes())
    h.update(" ".join((cflags or _CFLAGS) + _LDFLAGS).encode())
    h.update(torch.__version__.encode())
    h.update(sys.version.encode())
    h.update(_cpu_signature().encode())
    h.update(_ninja_program().encode())
    return h.hexdigest()[:16]


def build_directory(cflags: list[str] | None = None) -> Path:
    """Directory where the extension is (or will be) compiled."""
    root = os.environ.get("STEALTH_NS_CACHE")
    base = Path(root) if root else Path.home() / ".cache" / "stealth_ns"
    return base / "torch_ext" / _cache_key(cflags)


def load_extension() -> Any | None:
    """Compile (first use) and import the C++ extension; ``None`` if unavailable.

    Thread safe within a process; concurrent processes are serialised by torch's file baton in the
    build directory.  The failure reason is kept in :func:`compile_error`.
    """
    global _module, _error, _tried, _compile_seconds
    if _tried:
        return _module
    with _lock:
        if _tried:
            return _module
        if os.environ.get("STEALTH_NS_DISABLE_CPP", "").strip() not in ("", "0"):
            _error = "disabled by STEALTH_NS_DISABLE_CPP"
            _tried = True
            return None
        errors = []
        for extra in _FLAG_SETS:
            try:
                t0 = time.perf_counter()
                _module = load_build(extra)
                _compile_seconds = time.perf_counter() - t0
                _error = None
                break
            except Exception as exc:  # compiler missing, build error, import error, ...
                _module = None
                errors.append(f"[{' '.join(_BASE_CFLAGS + extra)}] {type(exc).__name__}: {exc}")
        if _module is None:
            _error = "; ".join(errors)
        _tried = True
        return _module


def load_build(extra_cflags: list[str]) -> Any:
    """Compile (or reuse from the cache) and import the extension built with the base flags plus
    ``extra_cflags``, one of ``_FLAG_SETS``: ``["-march=native"]`` (what :func:`load_extension` tries
    first) or ``[]``, the compiler's default target (x86-64's SSE2, aarch64's NEON: 4 floats a register).
    Raises whatever the build or the import raises."""
    from torch.utils import cpp_extension

    cflags = _BASE_CFLAGS + list(extra_cflags)
    build_dir = build_directory(cflags)
    try:
        build_dir.mkdir(parents=True, exist_ok=True)
    except OSError:  # read-only home: build in the temp dir instead
        build_dir = Path(tempfile.gettempdir()) / "stealth_ns" / "torch_ext" / build_dir.name
        build_dir.mkdir(parents=True, exist_ok=True)
    with _first_on_path(_ninja_program()):
        return cpp_extension.load(
            # distinct names: a failed import of one variant must not shadow the other
            name=EXTENSION_NAME if extra_cflags else f"{EXTENSION_NAME}_generic",
            sources=[str(path) for path in _SOURCES],
            extra_cflags=cflags,
            extra_ldflags=list(_LDFLAGS),
            build_directory=str(build_dir),
            with_cuda=False,
            verbose=os.environ.get("STEALTH_NS_VERBOSE_BUILD", "") not in ("", "0"),
        )


def compile_error() -> str | None:
    """Why :func:`load_extension` returned ``None`` (``None`` if it succeeded or was not tried)."""
    return _error


def compile_seconds() -> float | None:
    """Wall time of the (cached or fresh) build+import in this process, if it happened."""
    return _compile_seconds


def _require() -> Any:
    ext = load_extension()
    if ext is None:
        raise RuntimeError(f"stealth-ns C++ rasterizer unavailable: {compile_error()}")
    return ext


class RasterizeToPixelsCPU(torch.autograd.Function):
    """Autograd wrapper around ``rasterize_fwd`` / ``rasterize_bwd`` (gsplat's _RasterizeToPixels)."""

    @staticmethod
    def forward(
        ctx,
        means2d: Tensor,
        conics: Tensor,
        colors: Tensor,
        opacities: Tensor,
        backgrounds: Tensor | None,
        width: int,
        height: int,
        tile_size: int,
        isect_offsets: Tensor,
        flatten_ids: Tensor,
    ) -> tuple[Tensor, Tensor]:
        ext = _require()
        render_colors, render_alphas, last_ids, t_final = ext.rasterize_fwd(
            means2d,
            conics,
            colors,
            opacities,
            backgrounds,
            width,
            height,
            tile_size,
            isect_offsets,
            flatten_ids,
        )
        ctx.save_for_backward(
            means2d, conics, colors, opacities, backgrounds, isect_offsets, flatten_ids, t_final, last_ids
        )
        ctx.width = width
        ctx.height = height
        ctx.tile_size = tile_size
        return render_colors, render_alphas

    @staticmethod
    def backward(ctx, v_render_colors: Tensor | None, v_render_alphas: Tensor | None):
        (means2d, conics, colors, opacities, backgrounds, isect_offsets, flatten_ids, t_final, last_ids) = (
            ctx.saved_tensors
        )
        C, H, W = t_final.shape
        v_render_colors = _grad_or_zeros(v_render_colors, (C, H, W, colors.shape[-1]))
        v_render_alphas = _grad_or_zeros(v_render_alphas, (C, H, W, 1))
        ext = _require()
        with phase("backward: rasterize"):
            v_means2d, v_conics, v_colors, v_opacities = ext.rasterize_bwd(
                means2d,
                conics,
                colors,
                opacities,
                backgrounds,
                ctx.width,
                ctx.height,
                ctx.tile_size,
                isect_offsets,
                flatten_ids,
                t_final,
                last_ids,
                v_render_colors,
                v_render_alphas,
                True,
                DEFAULT_BWD_MODE,
            )
        v_backgrounds = None
        if backgrounds is not None and ctx.needs_input_grad[4]:
            v_backgrounds = (v_render_colors * t_final[..., None]).sum(dim=(1, 2))
        return v_means2d, v_conics, v_colors, v_opacities, v_backgrounds, None, None, None, None, None


def _f32(t: Tensor) -> Tensor:
    return t if (t.dtype == torch.float32 and t.is_contiguous()) else t.to(torch.float32).contiguous()


def _grad_or_zeros(grad: Tensor | None, shape: tuple[int, ...]) -> Tensor:
    """An upstream gradient as contiguous float32, zeros where autograd passed none."""
    return torch.zeros(shape, dtype=torch.float32) if grad is None else _f32(grad)


def _i32(t: Tensor) -> Tensor:
    return t if (t.dtype == torch.int32 and t.is_contiguous()) else t.to(torch.int32).contiguous()


def rasterize_to_pixels_cpp(
    means2d: Tensor,
    conics: Tensor,
    colors: Tensor,
    opacities: Tensor,
    image_width: int,
    image_height: int,
    tile_size: int,
    isect_offsets: Tensor,
    flatten_ids: Tensor,
    backgrounds: Tensor | None = None,
) -> tuple[Tensor, Tensor]:
    """gsplat's ``rasterize_to_pixels(..., packed=False)`` on the CPU.

    Args:
        means2d: [C, N, 2] projected means (pixels).
        conics: [C, N, 3] upper triangle (a, b, c) of the inverse 2D covariance.
        colors: [C, N, D] colours / features, any D >= 1.
        opacities: [C, N].
        image_width, image_height, tile_size: image and tile size in pixels.
        isect_offsets: [C, tile_height, tile_width] int32 start of each tile's list in ``flatten_ids``.
        flatten_ids: [n_isects] int32 indices into the flattened C*N Gaussians, sorted by
            (camera, tile, depth).
        backgrounds: optional [C, D].

    Returns:
        render_colors [C, H, W, D] and render_alphas [C, H, W, 1]; differentiable w.r.t. means2d,
        conics, colors, opacities and backgrounds.
    """
    C, N = means2d.shape[:2]
    assert means2d.shape == (C, N, 2), means2d.shape
    assert conics.shape == (C, N, 3), conics.shape
    assert colors.dim() == 3 and colors.shape[:2] == (C, N), colors.shape
    assert opacities.shape == (C, N), opacities.shape
    assert isect_offsets.dim() == 3 and isect_offsets.shape[0] == C, isect_offsets.shape
    tile_height, tile_width = isect_offsets.shape[1:3]
    assert tile_height * tile_size >= image_height, (tile_height, tile_size, image_height)
    assert tile_width * tile_size >= image_width, (tile_width, tile_size, image_width)
    for name, t in (("means2d", means2d), ("conics", conics), ("colors", colors), ("opacities", opacities)):
        if t.device.type != "cpu":
            raise ValueError(f"rasterize_to_pixels_cpp: {name} must be on the CPU, got {t.device}")
    if backgrounds is not None:
        assert backgrounds.shape == (C, colors.shape[-1]), backgrounds.shape
        backgrounds = _f32(backgrounds)
    return RasterizeToPixelsCPU.apply(
        _f32(means2d),
        _f32(conics),
        _f32(colors),
        _f32(opacities),
        backgrounds,
        int(image_width),
        int(image_height),
        int(tile_size),
        _i32(isect_offsets),
        _i32(flatten_ids),
    )


@torch.no_grad()
def rasterize_weights_cpp(
    means2d: Tensor,
    conics: Tensor,
    colors: Tensor,
    opacities: Tensor,
    image_width: int,
    image_height: int,
    tile_size: int,
    isect_offsets: Tensor,
    flatten_ids: Tensor,
) -> tuple[Tensor, Tensor, Tensor]:
    """:func:`rasterize_to_pixels_cpp`'s forward (no background, no gradient) and every Gaussian's
    blending weight: ``(render_colors [C, H, W, D], render_alphas [C, H, W, 1], weights [C, N])``, the
    weight being ``T * alpha`` summed over the pixels the Gaussian is blended into, which is the
    gradient of ``render_colors[..., k].sum()`` with respect to ``colors[..., k]``, without a backward."""
    return tuple(
        _require().rasterize_weights(
            _f32(means2d),
            _f32(conics),
            _f32(colors),
            _f32(opacities),
            None,
            int(image_width),
            int(image_height),
            int(tile_size),
            _i32(isect_offsets),
            _i32(flatten_ids),
        )
    )


@torch.no_grad()
def isect_tiles_cpp(
    means2d: Tensor,  # [C, N, 2]
    radii: Tensor,  # [C, N] int
    depths: Tensor,  # [C, N]
    tile_size: int,
    tile_width: int,
    tile_height: int,
    footprint: Footprint | None = None,
) -> tuple[Tensor, Tensor]:
    """gsplat's ``isect_tiles`` (sorted) + ``isect_offset_encode`` on the CPU; with ``footprint`` only
    the pairs whose tile the Gaussian's alpha >= 1/255 footprint reaches (:mod:`stealth_ns.raster.tiles`).

    Returns ``(isect_offsets [C, tile_height, tile_width] int32, flatten_ids [n_isects] int32)``,
    sorted by (camera, tile, depth), ties in depth by Gaussian index.
    """
    ext = _require()
    extra = {}
    if footprint is not None:
        extra = {
            "conics": _f32(footprint.conics.detach()),
            "opacities": _f32(footprint.opacities.detach()),
            "image_width": int(footprint.width),
            "image_height": int(footprint.height),
        }
    offsets, flatten_ids, _ = ext.isect_tiles(
        _f32(means2d.detach()),
        _i32(radii.detach()),
        _f32(depths.detach()),
        int(tile_size),
        int(tile_width),
        int(tile_height),
        **extra,
    )
    return offsets, flatten_ids


class ProjectGaussiansCPU(torch.autograd.Function):
    """Autograd wrapper around ``project_fwd`` / ``project_bwd``: :func:`projection.quat_scale_to_covar`
    followed by :func:`projection.project_gaussians` in one pass (no gradient for the cameras)."""

    @staticmethod
    def forward(
        ctx, means, quats, scales, viewmats, Ks, width, height, eps2d, near_plane, far_plane, radius_clip
    ):
        radii, means2d, depths, conics = _require().project_fwd(
            means, quats, scales, viewmats, Ks, width, height, eps2d, near_plane, far_plane, radius_clip
        )
        ctx.save_for_backward(means, quats, scales, viewmats, Ks, radii)
        ctx.size = (width, height, eps2d)
        ctx.mark_non_differentiable(radii)
        return radii, means2d, depths, conics

    @staticmethod
    def backward(ctx, _v_radii, v_means2d, v_depths, v_conics):
        means, quats, scales, viewmats, Ks, radii = ctx.saved_tensors
        with phase("backward: projection+SH"):
            v_means, v_quats, v_scales = _require().project_bwd(
                means,
                quats,
                scales,
                viewmats,
                Ks,
                *ctx.size,
                radii,
                _grad_or_zeros(v_means2d, (*radii.shape, 2)),
                _grad_or_zeros(v_depths, radii.shape),
                _grad_or_zeros(v_conics, (*radii.shape, 3)),
            )
        return v_means, v_quats, v_scales, None, None, None, None, None, None, None, None


class SphericalHarmonicsCPU(torch.autograd.Function):
    """Autograd wrapper around ``sh_fwd`` / ``sh_bwd``: per-camera colours
    ``max(SH(degree, means - camera centre, [dc, rest]) + 0.5, 0)``, 0 where the radius is 0. The
    coefficients stay split as the model stores them, so neither pass joins or splits ``[N, K, 3]``."""

    @staticmethod
    def forward(ctx, means, viewmats, sh_dc, sh_rest, degree, radii):
        colors = _require().sh_fwd(means, viewmats, sh_dc, sh_rest, degree, radii)
        ctx.save_for_backward(means, viewmats, sh_dc, sh_rest, radii)
        ctx.degree = degree
        return colors

    @staticmethod
    def backward(ctx, v_colors):
        means, viewmats, sh_dc, sh_rest, radii = ctx.saved_tensors
        with phase("backward: projection+SH"):
            v_dc, v_rest, v_means = _require().sh_bwd(
                means, viewmats, sh_dc, sh_rest, ctx.degree, radii, _f32(v_colors)
            )
        return v_means, None, v_dc, v_rest, None, None


def project_gaussians_cpp(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    viewmats: Tensor,
    Ks: Tensor,
    width: int,
    height: int,
    eps2d: float = 0.3,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    radius_clip: float = 0.0,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """:func:`projection.project_gaussians` of ``quat_scale_to_covar(quats, scales)``, compiled.

    Args:
        means: [N, 3]; quats: [N, 4] (w, x, y, z, any norm); scales: [N, 3] (not log).
        viewmats: [C, 4, 4] world-to-camera (OpenCV); Ks: [C, 3, 3]; no gradient flows to either.

    Returns:
        radii [C, N] int32, means2d [C, N, 2], depths [C, N], conics [C, N, 3], as the reference; the
        backward gives Gaussians of radius 0 no gradient (the rasterizer never reads them).
    """
    return ProjectGaussiansCPU.apply(
        _f32(means),
        _f32(quats),
        _f32(scales),
        _f32(viewmats.detach()),
        _f32(Ks.detach()),
        int(width),
        int(height),
        float(eps2d),
        float(near_plane),
        float(far_plane),
        float(radius_clip),
    )


def sh_colors_cpp(
    means: Tensor, viewmats: Tensor, coeffs: SHCoefficients, degree: int, radii: Tensor
) -> Tensor:
    """Per-camera colours ``[C, N, 3]`` of SH coefficients (the reference:
    ``clamp_min(spherical_harmonics(degree, means - camera centre, coeffs) + 0.5, 0)``), compiled; 0 for
    Gaussians of radius 0 in ``radii`` ``[C, N]``. ``coeffs`` is ``[N, K, 3]`` or, as the model stores
    them, the pair ``(dc [N, 3], rest [N, K - 1, 3])`` (no copy of either)."""
    if isinstance(coeffs, Tensor):
        sh_dc, sh_rest = coeffs[:, 0], coeffs[:, 1:]
    else:
        sh_dc, sh_rest = coeffs
    return SphericalHarmonicsCPU.apply(
        _f32(means), _f32(viewmats.detach()), _f32(sh_dc), _f32(sh_rest), int(degree), _i32(radii.detach())
    )
