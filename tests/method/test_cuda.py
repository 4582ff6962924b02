"""The CUDA path: gsplat's kernels against the compiled CPU backend, and a short poisoned run on a GPU.

Marked ``cuda`` and skipped on a machine without CUDA; ``make test-gpu`` runs only these.
"""

from __future__ import annotations

import json

import pytest
import torch
from conftest import train_tiny

from stealth_ns.raster import cpp_backend, rasterization

pytestmark = [
    pytest.mark.cuda,
    pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device"),
]

W, H = 64, 48


def _scene(n: int, sh_degree: int, seed: int = 0) -> dict[str, torch.Tensor]:
    """Gaussians in front of two cameras (the second off-axis), SH colours."""
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g) * 0.7 + torch.tensor([0.0, 0.0, 4.0])
    viewmats = torch.eye(4)[None].repeat(2, 1, 1)
    angle = torch.tensor(0.3)
    viewmats[1, :3, :3] = torch.tensor(
        [
            [torch.cos(angle), 0.0, torch.sin(angle)],
            [0.0, 1.0, 0.0],
            [-torch.sin(angle), 0.0, torch.cos(angle)],
        ]
    )
    viewmats[1, 0, 3] = -1.0
    K = torch.tensor([[60.0, 0.0, W / 2], [0.0, 60.0, H / 2], [0.0, 0.0, 1.0]])
    return {
        "means": means,
        "quats": torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1),
        "scales": torch.rand(n, 3, generator=g) * 0.08 + 0.02,
        "opacities": torch.rand(n, generator=g) * 0.9 + 0.05,
        "colors": torch.randn(n, (sh_degree + 1) ** 2, 3, generator=g) * 0.3,
        "viewmats": viewmats,
        "Ks": K[None].repeat(2, 1, 1),
    }


def _render(scene: dict[str, torch.Tensor], backend: str, device: str, sh_degree: int):
    """Images, alphas and the gradients of every Gaussian parameter of one loss, on ``device``."""
    names = ("means", "quats", "scales", "opacities", "colors")
    leaves = {k: scene[k].to(device).requires_grad_(True) for k in names}
    target = torch.linspace(0, 1, 2 * H * W * 3, device=device).reshape(2, H, W, 3)
    img, alpha, info = rasterization(
        **leaves,
        viewmats=scene["viewmats"].to(device),
        Ks=scene["Ks"].to(device),
        width=W,
        height=H,
        sh_degree=sh_degree,
        packed=False,
        backend=backend,
    )
    ((img - target).abs().mean() + alpha.mean()).backward()
    return img.detach().cpu(), alpha.detach().cpu(), {k: v.grad.cpu() for k, v in leaves.items()}, info


@pytest.mark.skipif(cpp_backend.load_extension() is None, reason="C++ extension unavailable")
@pytest.mark.parametrize("sh_degree", [0, 3])
def test_gsplat_matches_compiled_cpu_backend(sh_degree):
    scene = _scene(2000, sh_degree)
    img_gpu, alpha_gpu, grads_gpu, info_gpu = _render(scene, "gsplat", "cuda", sh_degree)
    img_cpu, alpha_cpu, grads_cpu, info_cpu = _render(scene, "cpp", "cpu", sh_degree)
    drawn_gpu, drawn_cpu = info_gpu["radii"].cpu() > 0, info_cpu["radii"] > 0
    assert drawn_cpu.sum() > 1000
    assert (drawn_gpu == drawn_cpu).float().mean() > 0.995  # float rounding may flip a border case
    # gsplat blends with the approximate __expf; ours with a ~1 ulp expf: close, not bitwise
    torch.testing.assert_close(img_cpu, img_gpu, rtol=0, atol=2e-3)
    torch.testing.assert_close(alpha_cpu, alpha_gpu, rtol=0, atol=2e-3)
    for name, ref in grads_gpu.items():
        got = grads_cpu[name]
        assert (got - ref).abs().max() <= 1e-2 * ref.abs().max(), name
        cosine = torch.nn.functional.cosine_similarity(got.flatten(), ref.flatten(), dim=0)
        assert cosine > 0.999, (name, float(cosine))


def test_view_noise_drawn_on_the_gpu_is_the_cpus():
    """The view noise of a GPU-cached image is drawn on the GPU, bitwise what the CPU draws."""
    from stealth_ns.attack.normal_draw import noisy_uint8, normal_deviates, normal_deviates_reference

    for count, key in ((1, 0), (70_001, 2**63 - 1), (756 * 1008 * 3, 987654321)):
        got = normal_deviates((count,), key, "cuda")
        assert got.device.type == "cuda"
        assert got.cpu().numpy().tobytes() == normal_deviates_reference(count, key).tobytes(), (count, key)
    image = torch.randint(0, 256, (97, 131, 3), dtype=torch.uint8, generator=torch.Generator().manual_seed(0))
    for sigma in (0.5, 12.3, 300.0):
        on_gpu = noisy_uint8(image.cuda(), sigma, 42)
        assert on_gpu.device.type == "cuda" and torch.equal(on_gpu.cpu(), noisy_uint8(image, sigma, 42))


def test_view_noise_replayed_as_cuda_graphs_is_the_cpus():
    """The view noise of a GPU-cached image runs as one CUDA graph per shape, bitwise the CPU's; the
    shapes interleaved, and each call's output its own (the graph's buffer is reused)."""
    from stealth_ns.attack import normal_draw

    g = torch.Generator().manual_seed(3)
    images = [
        torch.randint(0, 256, shape, dtype=torch.uint8, generator=g)
        for shape in ((97, 131, 3), (756, 1008, 3))
    ]
    normal_draw._noise_graphs.clear()
    outputs = []
    for sigma, key in ((0.5, 0), (12.3, 2**63 - 1), (300.0, 987654321)):  # the key's whole domain
        for image in images:
            got = normal_draw.noisy_uint8(image.cuda(), sigma, key)
            outputs.append((got, normal_draw.noisy_uint8(image, sigma, key)))
    assert normal_draw._noise_graphs_off == "" and len(normal_draw._noise_graphs) == 2
    for got, expected in outputs:  # compared after all calls: no output was overwritten by a later replay
        assert got.device.type == "cuda" and torch.equal(got.cpu(), expected)


@pytest.mark.slow
def test_short_poisoned_run_on_the_gpu(tiny_orbit_scene, tmp_path):
    """stealth-splat-lite with the attack on a CUDA device: gsplat renders, the poison is injected,
    the attack record is written."""
    config = train_tiny(
        tiny_orbit_scene,
        tmp_path,
        "gpu",
        "--machine.device-type",
        "cuda",
        "--pipeline.attack.injection-step",
        "20",
        iterations=100,
    )
    run = config.parent
    record = json.loads((run / "attack" / "attack.json").read_text())
    assert record["injection_step"] == 20
    assert (run / "attack" / "poison_points.ply").exists()
    checkpoint = next((run / "nerfstudio_models").glob("step-*.ckpt"))
    state = torch.load(checkpoint, map_location="cpu", weights_only=False)["pipeline"]
    assert state["_model.gauss_params.poison"].sum() > 0  # the poison rows were trained and kept


@pytest.mark.slow
def test_scan_on_the_gpu_names_the_poisoned_view(tiny_orbit_scene, tmp_path):
    """stealth-ns scan renders with gsplat on CUDA: a poisoned run is suspicious and its poisoned view is
    the one named."""
    from stealth_ns.runs.imported import load_model
    from stealth_ns.scan.config import ScanConfig
    from stealth_ns.scan.scanner import scan_model

    config = train_tiny(
        tiny_orbit_scene, tmp_path, "scan", "--pipeline.attack.injection-step", "20", iterations=300
    )
    on_gpu = scan_model(load_model(config), ScanConfig())  # the run loads on CUDA when there is one
    assert str(on_gpu.model.run.model.device).startswith("cuda")
    assert on_gpu.verdict == "suspicious"
    record = json.loads((config.parent / "attack" / "attack.json").read_text())
    assert [g.name for g in on_gpu.targeted] == [v["name"] for v in record["poisoned_views"]]
