"""Benchmark of the CPU rasterizers: compiled C++ (``cpp``) vs pure PyTorch (``torch``).

Times the full pipeline a training step runs -- ``stealth_ns.raster.rasterization`` with SH
degree 3 colours: projection, SH evaluation, tile intersection + sort, rasterize-to-pixels --
forward alone and forward + backward (an L1 loss against a fixed target image), as the median
of repeated runs after warm-up, all in one process.  The workloads are synthetic, fixed-seed
random Gaussians in front of one pinhole camera with footprints of a few pixels.

``run_raster_benchmark()`` returns (and optionally writes as JSON) the measurements; the CLI
``stealth-ns bench raster [--json FILE]`` calls it.

The process's freed memory is kept for reuse as in CPU training (:func:`keep_freed_memory`). With
glibc's defaults every call's outputs would be fresh pages, and their page faults (with TLB
flushes that interrupt the other cores) would be timed too (docs/design/cpu_rasterizer.md, "Benchmark", has
both measurements).
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from stealth_ns.foundation.malloc_tuning import keep_freed_memory

__all__ = ["BenchCase", "DEFAULT_CASES", "make_synthetic_scene", "run_raster_benchmark"]


@dataclass(frozen=True)
class BenchCase:
    name: str
    n_gaussians: int
    width: int
    height: int


DEFAULT_CASES: tuple[BenchCase, ...] = (
    BenchCase("10k@128x128", 10_000, 128, 128),
    BenchCase("50k@256x256", 50_000, 256, 256),
    BenchCase("200k@512x512", 200_000, 512, 512),
)

SH_DEGREE = 3


def make_synthetic_scene(n: int, width: int, height: int, seed: int = 0) -> dict[str, torch.Tensor]:
    """Random Gaussians in front of a camera at the origin looking down +z (OpenCV axes).

    Depths uniform in [2, 10]; image-plane positions uniform over the image (+5% margin);
    per-axis screen-space standard deviation log-normal around 1.2 px (so 3-sigma radii of
    ~4-6 px after gsplat's 0.3 px² blur); random rotations; opacities sigmoid(N(0, 1)); SH
    degree-3 coefficients N(0, 0.2^2).
    """
    g = torch.Generator().manual_seed(seed)
    f = 0.8 * width
    z = 2.0 + 8.0 * torch.rand(n, generator=g)
    u = (torch.rand(n, generator=g) * 1.1 - 0.05) * width
    v = (torch.rand(n, generator=g) * 1.1 - 0.05) * height
    means = torch.stack([(u - width / 2) / f * z, (v - height / 2) / f * z, z], dim=-1)
    sigma_px = torch.exp(torch.randn(n, 3, generator=g) * 0.4) * 1.2
    scales = sigma_px * z[:, None] / f
    quats = torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1)
    opacities = torch.sigmoid(torch.randn(n, generator=g))
    sh = torch.randn(n, (SH_DEGREE + 1) ** 2, 3, generator=g) * 0.2
    Ks = torch.tensor([[[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]]])
    target = torch.rand(1, height, width, 3, generator=g)
    return {
        "means": means,
        "quats": quats,
        "scales": scales,
        "opacities": opacities,
        "colors": sh,
        "viewmats": torch.eye(4)[None],
        "Ks": Ks,
        "target": target,
    }


def _make_step(rasterization, leaves, viewmats, Ks, case: BenchCase, target, backend: str):
    """(forward, forward_backward) closures of one training-like step."""

    def forward():
        return rasterization(
            leaves["means"],
            leaves["quats"],
            leaves["scales"],
            leaves["opacities"],
            leaves["colors"],
            viewmats,
            Ks,
            case.width,
            case.height,
            sh_degree=SH_DEGREE,
            backend=backend,
        )

    def forward_backward():
        for t in leaves.values():
            t.grad = None
        rc, ra, _ = forward()
        loss = (rc - target).abs().mean() + 0.01 * ra.mean()
        loss.backward()

    return forward, forward_backward


def _median_ms(fn: Callable[[], Any], repeats: int, warmup: int) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def _machine_info() -> dict[str, Any]:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    info: dict[str, Any] = {
        "platform": platform.platform(),
        "cpu": cpu,
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "python": platform.python_version(),
    }
    try:
        info["load_average"] = os.getloadavg()
    except OSError:
        pass
    return info


def run_raster_benchmark(
    cases: Sequence[BenchCase | tuple[str, int, int, int]] | None = None,
    repeats: int = 10,
    warmup: int = 2,
    json_path: str | os.PathLike | None = None,
    backends: Sequence[str] = ("cpp", "torch"),
    reference_repeats: int = 3,
    reference_budget_s: float = 300.0,
    threads: int | None = None,
    verbose: bool = True,
) -> dict[str, Any]:
    """Time forward and forward+backward of the full CPU rasterization pipeline.

    Args:
        cases: workloads (default :data:`DEFAULT_CASES`: 10k@128², 50k@256², 200k@512²).
        repeats, warmup: timed runs (median reported) and untimed warm-up runs for ``cpp``.
        json_path: if given, the result is also written there as JSON.
        backends: backends of ``stealth_ns.raster.rasterization`` to time.
        reference_repeats: timed runs for the slow ``torch`` backend (1 warm-up run).
        reference_budget_s: the ``torch`` backend is skipped for a case (with a note) when its
            predicted time -- per-intersection cost measured on the previous case times this
            case's intersection count, times (warm-up + 2 * repeats) -- exceeds this budget;
            otherwise its repeats are reduced to fit.  ``math.inf`` never skips.
        threads: ``torch.set_num_threads`` (and OpenMP threads of the kernel); default: unchanged.
        verbose: print progress and the final table.

    Returns:
        ``{"cases": [{"name", "n_gaussians", "width", "height", "backend", "forward_ms",
        "forward_backward_ms", "n_isects", "repeats", "note"}, ...], "speedup_fwd_bwd":
        {case: torch / cpp}, "speedup_fwd": {...}, "machine": {...}, "settings": {...}}``;
        skipped runs have ``forward_ms = forward_backward_ms = None`` and a ``note``.
    """
    from stealth_ns.raster import cpp_backend

    if threads is not None:
        torch.set_num_threads(int(threads))
    case_list = [c if isinstance(c, BenchCase) else BenchCase(*c) for c in (cases or DEFAULT_CASES)]
    say = print if verbose else (lambda *a, **k: None)
    memory_kept = keep_freed_memory()  # as a CPU training does (see the module docstring)
    compile_s = _load_cpp() if "cpp" in backends else None

    rows: list[dict[str, Any]] = []
    ref_cost_per_isect: float | None = None  # seconds of one torch fwd+bwd per intersection
    for case in case_list:
        workload = _Workload.of(case)
        for backend in backends:
            row: dict[str, Any] = {
                "name": case.name,
                "n_gaussians": case.n_gaussians,
                "width": case.width,
                "height": case.height,
                "backend": backend,
                "forward_ms": None,
                "forward_backward_ms": None,
                "n_isects": workload.n_isects,
                "repeats": 0,
                "note": "",
            }
            if backend == "cpp":
                n_rep, n_warm = repeats, warmup
            else:
                n_warm = 1
                n_rep, row["note"] = _reference_repeats(
                    reference_repeats, ref_cost_per_isect, workload.n_isects, reference_budget_s
                )
                if n_rep == 0:
                    say(f"[bench] {case.name} {backend}: {row['note']}")
                    rows.append(row)
                    continue
            say(f"[bench] {case.name} {backend}: {n_warm} warm-up + {n_rep} timed runs ...", flush=True)
            t_case = time.perf_counter()
            f_ms, fb_ms = workload.time_step(backend, n_rep, n_warm)
            if backend != "cpp" and workload.n_isects > 0:
                ref_cost_per_isect = fb_ms / 1e3 / workload.n_isects
            row.update(forward_ms=f_ms, forward_backward_ms=fb_ms, repeats=n_rep)
            say(
                f"[bench] {case.name} {backend}: forward {f_ms:.1f} ms, forward+backward {fb_ms:.1f} ms "
                f"({time.perf_counter() - t_case:.1f} s)"
            )
            rows.append(row)

    speedup_fb, speedup_f = _speedups(case_list, rows)
    result = {
        "cases": rows,
        "speedup_fwd_bwd": speedup_fb,
        "speedup_fwd": speedup_f,
        "machine": _machine_info(),
        "settings": {
            "repeats": repeats,
            "warmup": warmup,
            "reference_repeats": reference_repeats,
            "reference_budget_s": reference_budget_s,
            "sh_degree": SH_DEGREE,
            "pipeline": "stealth_ns.raster.rasterization (projection + SH + tiles + rasterize), L1 loss",
            "cpp_load_s": compile_s,
            "cpp_build_dir": str(cpp_backend.build_directory()) if "cpp" in backends else None,
            "freed_memory_kept": memory_kept,
        },
    }
    if verbose:
        print(format_table(result))
    if json_path is not None:
        path = Path(json_path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(result, indent=2) + "\n")
    return result


def _load_cpp() -> float:
    """Build (or load the cached) compiled kernel; the seconds it took. RuntimeError if it fails."""
    from stealth_ns.raster import cpp_backend

    t0 = time.perf_counter()
    ext = cpp_backend.load_extension()
    compile_s = time.perf_counter() - t0
    if ext is None:
        raise RuntimeError(f"compiled CPU rasterizer unavailable: {cpp_backend.compile_error()}")
    return compile_s


@dataclass
class _Workload:
    """One case's scene: trainable leaves (means, quats, scales, opacities, SH colours), the camera,
    the L1 target and the number of (tile, Gaussian) intersections."""

    case: BenchCase
    leaves: dict[str, torch.Tensor]
    viewmats: torch.Tensor
    Ks: torch.Tensor
    target: torch.Tensor
    n_isects: int

    @classmethod
    def of(cls, case: BenchCase) -> _Workload:
        from stealth_ns.raster.projection import project_gaussians, quat_scale_to_covar
        from stealth_ns.raster.tiles import isect_tiles, tile_grid

        scene = make_synthetic_scene(case.n_gaussians, case.width, case.height)
        target = scene.pop("target")
        viewmats, Ks = scene.pop("viewmats"), scene.pop("Ks")
        with torch.no_grad():
            covars = quat_scale_to_covar(scene["quats"], scene["scales"])
            radii, means2d, depths, _ = project_gaussians(
                scene["means"], covars, viewmats, Ks, case.width, case.height
            )
            tw, th = tile_grid(case.width, case.height, 16)
            n_isects = int(isect_tiles(means2d, radii, depths, 16, tw, th)[1].numel())
        leaves = {k: v.clone().requires_grad_(True) for k, v in scene.items()}
        return cls(case, leaves, viewmats, Ks, target, n_isects)

    def time_step(self, backend: str, repeats: int, warmup: int) -> tuple[float, float]:
        """Median milliseconds of forward and of forward + backward on ``backend``, after ``warmup``
        forward + backward runs (which also warm the forward path)."""
        from stealth_ns.raster import rasterization

        forward, forward_backward = _make_step(
            rasterization, self.leaves, self.viewmats, self.Ks, self.case, self.target, backend
        )
        for _ in range(warmup):
            forward_backward()
        fb_ms = _median_ms(forward_backward, repeats, 0)
        with torch.enable_grad():
            f_ms = _median_ms(forward, repeats, 0)
        return f_ms, fb_ms


def _reference_repeats(
    repeats: int, cost_per_isect: float | None, n_isects: int, budget_s: float
) -> tuple[int, str]:
    """Timed runs of the slow ``torch`` backend within ``budget_s`` seconds, predicted from the
    previous case's cost per intersection (unknown for the first case: ``repeats``), and a note:
    0 runs when even one would not fit (with 1 warm-up and forward + backward twice per run)."""
    if cost_per_isect is None:
        return repeats, ""
    predicted = cost_per_isect * n_isects
    if predicted * (1 + 2 * repeats) <= budget_s:
        return repeats, ""
    fit = int((budget_s / predicted - 1) // 2)
    if fit < 1:
        return 0, (
            f"skipped: predicted {predicted:.0f} s per forward+backward "
            f"(x3 runs) exceeds the {budget_s:.0f} s budget"
        )
    return fit, f"repeats reduced to {fit} to fit the {budget_s:.0f} s budget"


def _speedups(
    cases: Sequence[BenchCase], rows: list[dict[str, Any]]
) -> tuple[dict[str, float | None], dict[str, float | None]]:
    """Per case, torch / cpp time of forward + backward and of forward (None unless both ran)."""
    speedup_fb: dict[str, float | None] = {}
    speedup_f: dict[str, float | None] = {}
    for case in cases:
        by = {r["backend"]: r for r in rows if r["name"] == case.name}
        cpp, ref = by.get("cpp"), by.get("torch")
        ok = cpp and ref and cpp["forward_backward_ms"] and ref["forward_backward_ms"]
        speedup_fb[case.name] = ref["forward_backward_ms"] / cpp["forward_backward_ms"] if ok else None
        speedup_f[case.name] = ref["forward_ms"] / cpp["forward_ms"] if ok else None
    return speedup_fb, speedup_f


def format_table(result: dict[str, Any]) -> str:
    """The measurements as a plain-text table."""

    def ms(v):
        return f"{v:10.1f}" if v is not None else f"{'-':>10}"

    lines = [
        f"{'case':<14} {'backend':<7} {'isects':>8} {'fwd ms':>10} {'fwd+bwd ms':>11} {'speedup':>8}  note",
        "-" * 72,
    ]
    for r in result["cases"]:
        sp = result["speedup_fwd_bwd"].get(r["name"]) if r["backend"] == "cpp" else None
        sp_s = f"{sp:7.1f}x" if sp else f"{'':>8}"
        lines.append(
            f"{r['name']:<14} {r['backend']:<7} {r['n_isects']:>8} {ms(r['forward_ms'])} "
            f"{ms(r['forward_backward_ms']):>11} {sp_s}  {r['note']}"
        )
    m = result["machine"]
    lines.append(f"speedup = torch / cpp forward+backward; {m['cpu']}, {m['torch_threads']} threads")
    return "\n".join(lines)
