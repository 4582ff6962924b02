"""The compiled kernels built for the compiler's default target give the bits of the native build.

The default target (no ``-march``: SSE2 on x86-64, NEON on aarch64) has 4 floats per register, so the
kernels take their 4-lane paths there: the projection, SH and SSIM kernels 4 lanes at a time, and the
rasterizer's 8-pixel blocks with their comparisons and selects applied half by half
(``rasterize_cpu.cpp``, ``V_SEL``).  This is the build a machine gets where ``-march=native`` fails, and
on x86 it is how CI checks the code that aarch64 runs.
"""

from __future__ import annotations

import pytest
import torch
from raster_cases import intrinsics, look_at_viewmat, random_gaussians

from stealth_ns.attack import normal_draw
from stealth_ns.images.ssim import SSIM, l1_ssim_loss
from stealth_ns.raster import cpp_backend

pytestmark = pytest.mark.slow  # a second build of the kernels: ~1-2 min on 2 cores

W, H, TILE = 160, 120, 16
TILES_X, TILES_Y = -(-W // TILE), -(-H // TILE)  # 10 x 8 tiles, the last row partly outside


@pytest.fixture(scope="module")
def builds():
    native = cpp_backend.load_extension()
    assert native is not None, f"C++ kernels failed to compile: {cpp_backend.compile_error()}"
    if native.__name__.endswith("_generic"):
        pytest.skip("-march=native was rejected here: the native build is the generic one")
    return native, cpp_backend.load_build([])


def _pipeline() -> dict[str, torch.Tensor]:
    """Projection, SH colours, tile lists, rasterization with a background, L1 + SSIM loss and all
    gradients back to the Gaussians' parameters, for two cameras; then the attack's view noise."""
    g = torch.Generator().manual_seed(5)
    means, quats, scales, opacities, sh = random_gaussians(3000, seed=3, spread=1.5, sh_degree=2)
    leaves = [t.clone().requires_grad_(True) for t in (means, quats, scales, opacities, sh)]
    viewmats = torch.stack([look_at_viewmat((0.0, 0.5, 4.0)), look_at_viewmat((3.0, -0.5, 2.5))])
    Ks = torch.stack([intrinsics(W, H), intrinsics(W, H, 50.0)])
    radii, means2d, depths, conics = cpp_backend.project_gaussians_cpp(
        leaves[0], leaves[1], leaves[2], viewmats, Ks, W, H, eps2d=0.3
    )
    colors = cpp_backend.sh_colors_cpp(leaves[0], viewmats, (leaves[4][:, 0], leaves[4][:, 1:]), 2, radii)
    offsets, flatten_ids = cpp_backend.isect_tiles_cpp(means2d, radii, depths, TILE, TILES_X, TILES_Y)
    C, N = radii.shape
    image, alpha = cpp_backend.rasterize_to_pixels_cpp(
        means2d,
        conics,
        colors,
        torch.sigmoid(leaves[3]).expand(C, N).contiguous(),
        W,
        H,
        TILE,
        offsets,
        flatten_ids,
        backgrounds=torch.tensor([[0.1, 0.2, 0.3]] * C),
    )
    gt = torch.rand(C, H, W, 3, generator=g)
    ssim = SSIM(data_range=1.0, size_average=True, channel=3)
    loss = l1_ssim_loss(image[0], gt[0], ssim, 0.2) + (image[1] - gt[1]).abs().mean()
    loss.backward()
    out = {"radii": radii, "means2d": means2d, "conics": conics, "colors": colors, "image": image}
    out |= {"alpha": alpha, "flatten_ids": flatten_ids, "loss": loss}
    out |= {f"grad {i}": leaf.grad for i, leaf in enumerate(leaves)}
    out["noise"] = normal_draw.normal_deviates((1001,), key=12345)
    out["noisy"] = normal_draw.noisy_uint8((gt[0] * 255).to(torch.uint8), 8.0, 99)
    return {k: v.detach() for k, v in out.items()}


def test_the_generic_build_gives_the_native_builds_bits(builds, monkeypatch):
    native, generic = builds
    assert generic is not native
    runs = []
    for module in (native, generic):
        monkeypatch.setattr(cpp_backend, "_module", module)
        runs.append(_pipeline())
    assert (runs[0]["radii"] > 0).sum() > 1000 and runs[0]["flatten_ids"].numel() > 5000
    assert runs[0]["grad 3"].abs().max() > 0
    differ = [name for name in runs[0] if not torch.equal(runs[0][name], runs[1][name])]
    assert not differ, f"the generic build differs in {differ}"
