"""The pure-PyTorch rasterizer against the brute-force reference, finite differences and gsplat's math."""

from __future__ import annotations

import pytest
import torch
from raster_cases import CASES, behind_and_outside_case, make_case
from raster_reference import brute_force_render

from stealth_ns.raster import rasterization
from stealth_ns.raster.projection import project_gaussians, quat_scale_to_covar, spherical_harmonics

PARAMS = ("means", "quats", "scales", "opacities", "colors")


def _render(case, backend, render_mode="RGB+D", backgrounds=None):
    return rasterization(**case, backend=backend, render_mode=render_mode, backgrounds=backgrounds)


def _grads(case, fn):
    leaves = {k: case[k].clone().requires_grad_(True) for k in PARAMS}
    img, alpha = fn({**case, **leaves})[:2]
    w = torch.linspace(0.5, 1.5, img.numel()).reshape(img.shape)  # non-uniform weights per channel/pixel
    ((img * w).sum() + (alpha * 0.7).sum()).backward()
    return {k: v.grad for k, v in leaves.items()}


def _assert_rel(a: torch.Tensor, b: torch.Tensor, rtol: float = 1e-3, atol: float = 1e-6):
    err = (a - b).norm()
    assert err <= rtol * b.norm() + atol, f"relative error {float(err / (b.norm() + 1e-30)):.2e}"


@pytest.mark.parametrize("name", CASES)
@pytest.mark.parametrize("mode", ["RGB+D", "RGB+ED", "D"])
def test_torch_backend_matches_brute_force(name, mode):
    case = make_case(name)
    C = case["viewmats"].shape[0]
    bg = torch.rand(C, 3) if mode.startswith("RGB") else None
    img, alpha, info = _render(case, "torch", mode, bg)
    ref_img, ref_alpha = brute_force_render(**case, backgrounds=bg, render_mode=mode)
    assert img.shape == (C, case["height"], case["width"], ref_img.shape[-1])
    assert info["radii"].shape == (C, case["means"].shape[0])
    torch.testing.assert_close(alpha, ref_alpha, atol=1e-4, rtol=0)
    if mode == "RGB+ED":  # expected depth divides by alpha: compare where something was hit
        hit = ref_alpha[..., 0] > 1e-3
        torch.testing.assert_close(img[hit], ref_img[hit], atol=1e-4, rtol=1e-4)
    else:
        torch.testing.assert_close(img, ref_img, atol=1e-4, rtol=1e-4)


@pytest.mark.parametrize(
    "name", ["basic", "two_cameras_sh3", "non_square_odd", "anisotropic", "dense_opaque"]
)
def test_torch_backend_gradients_match_brute_force(name):
    case = make_case(name)
    got = _grads(case, lambda c: _render(c, "torch"))
    ref = _grads(case, lambda c: brute_force_render(**c, render_mode="RGB+D"))
    for k in PARAMS:
        _assert_rel(got[k], ref[k])


def test_finite_differences_float64():
    case = make_case("basic")
    case = {k: (v.double() if torch.is_tensor(v) else v) for k, v in case.items()}

    def loss(**over):
        img, alpha, _ = _render({**case, **over}, "torch")
        w = torch.linspace(0.5, 1.5, img.numel(), dtype=torch.float64).reshape(img.shape)
        return (img * w).sum() + alpha.sum()

    leaves = {k: case[k].clone().requires_grad_(True) for k in PARAMS}
    loss(**leaves).backward()
    eps = 1e-6
    # a few coordinates of Gaussians that are on screen
    visible = torch.nonzero(_render(case, "torch")[2]["radii"][0] > 0)[:, 0][:4].tolist()
    for k in PARAMS:
        for gi in visible:
            for j in range(case[k][gi].numel() if case[k].dim() > 1 else 1):
                plus, minus = case[k].clone(), case[k].clone()
                if case[k].dim() > 1:
                    plus[gi].view(-1)[j] += eps
                    minus[gi].view(-1)[j] -= eps
                    analytic = leaves[k].grad[gi].reshape(-1)[j]
                else:
                    plus[gi] += eps
                    minus[gi] -= eps
                    analytic = leaves[k].grad[gi]
                numeric = (loss(**{k: plus}) - loss(**{k: minus})) / (2 * eps)
                assert abs(float(analytic - numeric)) <= 1e-3 * max(1.0, abs(float(numeric))), (k, gi, j)


def test_behind_camera_and_off_screen_are_not_rendered():
    case = behind_and_outside_case()
    img, alpha, info = _render(case, "torch")
    ref_img, ref_alpha = brute_force_render(**case, render_mode="RGB+D")
    assert (info["radii"][0, :10] == 0).all()
    torch.testing.assert_close(img, ref_img, atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(alpha, ref_alpha, atol=1e-4, rtol=0)


def test_zero_gaussians_render_background():
    case = make_case("zero")
    bg = torch.tensor([[0.2, 0.4, 0.6]])
    img, alpha, _ = _render(case, "torch", "RGB", bg)
    assert torch.equal(alpha, torch.zeros_like(alpha))
    torch.testing.assert_close(img, bg.reshape(1, 1, 1, 3).expand_as(img))


def test_projection_and_sh_match_gsplat_pure_torch():
    from gsplat.cuda._torch_impl import _fully_fused_projection, _spherical_harmonics

    case = make_case("two_cameras_sh3")
    covars = quat_scale_to_covar(case["quats"], case["scales"])
    ours = project_gaussians(
        case["means"], covars, case["viewmats"], case["Ks"], case["width"], case["height"]
    )
    radii, means2d, depths, conics, _ = _fully_fused_projection(
        case["means"], covars, case["viewmats"], case["Ks"], case["width"], case["height"]
    )
    assert torch.equal(ours[0], radii)
    for a, b in zip(ours[1:], (means2d, depths, conics), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-5)
    dirs = torch.randn(50, 3)
    coeffs = torch.randn(50, 16, 3)
    for degree in range(4):
        torch.testing.assert_close(
            spherical_harmonics(degree, dirs, coeffs),
            _spherical_harmonics(degree, dirs, coeffs),
            rtol=1e-5,
            atol=1e-5,
        )


def test_memory_is_bounded_for_large_images():
    """256x256 with 50k Gaussians: peak memory of forward+backward stays within a few GB."""
    import resource

    from raster_cases import intrinsics, look_at_viewmat, random_gaussians

    means, quats, scales, opac, colors = random_gaussians(50_000, seed=3, spread=1.5, scale=(0.005, 0.03))
    leaves = [t.requires_grad_(True) for t in (means, quats, scales, opac, colors)]
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    img, alpha, _ = rasterization(
        *leaves,
        look_at_viewmat((0.0, 0.5, -4.0))[None],
        intrinsics(256, 256)[None],
        256,
        256,
        backend="torch",
    )
    img.sum().backward()
    grown_gb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024**2
    assert means.grad is not None and torch.isfinite(means.grad).all()
    assert grown_gb < 3.0, f"peak RSS grew by {grown_gb:.2f} GB"


def test_alpha_clamp_and_exclusive_termination_hand_computed():
    """Two fully opaque Gaussians centred on pixel (20, 15): the front one gives alpha 0.999
    (gsplat's clamp); the back one would bring T to 1e-6 <= 1e-4, so it is not blended."""
    K = torch.tensor([[[30.0, 0.0, 20.5], [0.0, 30.0, 15.5], [0.0, 0.0, 1.0]]])
    means = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 3.0]])
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 2)
    scales = torch.full((2, 3), 0.1)
    colors = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    for backend in ("torch",):
        img, alpha, _ = rasterization(
            means, quats, scales, torch.ones(2), colors, torch.eye(4)[None], K, 40, 30, backend=backend
        )
        assert float(alpha[0, 15, 20, 0]) == pytest.approx(0.999, abs=1e-6)
        torch.testing.assert_close(img[0, 15, 20], torch.tensor([0.999, 0.0, 0.0]), atol=1e-6, rtol=0)
