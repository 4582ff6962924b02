"""What produced a figure: package versions, hardware and thread count.

Same seed and same thread count give bit-identical trainings on one software/hardware stack;
across stacks (another torch wheel, another CPU's vector units) floating-point sums differ and
so do the figures. Every result file records this so a difference can be traced.
"""

from __future__ import annotations

import os
import platform
from importlib.metadata import PackageNotFoundError, version
from typing import Any

PACKAGES = ("torch", "nerfstudio", "gsplat", "numpy", "scipy", "open3d", "pycolmap", "stealth-ns")


def _version(name: str) -> str | None:
    try:
        return version(name)
    except PackageNotFoundError:
        return None


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), or the platform's processor string."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def software_and_hardware() -> dict[str, Any]:
    """Versions of the packages that shape the numbers, Python, the CPU/GPU and torch's threads."""
    import torch

    cuda = torch.cuda.is_available()
    return {
        "python": platform.python_version(),
        "platform": platform.platform(),
        **{name.replace("-", "_"): _version(name) for name in PACKAGES},
        "device": torch.cuda.get_device_name(0) if cuda else "cpu",
        "cpu": cpu_model(),
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
    }
