"""The compiled projection + SH kernels (csrc/project_cpu.cpp) against the readable torch reference
(stealth_ns/raster/projection.py): values and gradients."""

from __future__ import annotations

import pytest
import torch
from raster_cases import intrinsics, look_at_viewmat, random_gaussians

from stealth_ns.raster import cpp_backend
from stealth_ns.raster.projection import project_gaussians, quat_scale_to_covar, spherical_harmonics

pytestmark = pytest.mark.skipif(cpp_backend.load_extension() is None, reason="C++ extension unavailable")

W, H = 48, 36


def _cameras(eyes) -> tuple[torch.Tensor, torch.Tensor]:
    viewmats = torch.stack([look_at_viewmat(eye) for eye in eyes])
    Ks = torch.stack([intrinsics(W, H, fov) for fov in (60.0, 45.0, 75.0)[: len(eyes)]])
    Ks[:, 0, 2] += torch.tensor([0.0, 3.5, -2.0])[: len(eyes)]  # off-centre principal points
    return viewmats, Ks


def _scene(n: int, seed: int, eyes, spread: float = 3.0):
    means, quats, scales, _, coeffs = random_gaussians(n, seed=seed, spread=spread, sh_degree=3)
    quats = quats * torch.rand(n, 1, generator=torch.Generator().manual_seed(seed + 1)).add(0.5)  # any norm
    viewmats, Ks = _cameras(eyes)
    return means, quats, scales, coeffs, viewmats, Ks


def _reference_projection(means, quats, scales, viewmats, Ks, **kw):
    return project_gaussians(means, quat_scale_to_covar(quats, scales), viewmats, Ks, W, H, **kw)


EYES = {
    "one": [(0.0, 0.3, -4.0)],
    # the second camera is inside the cloud: Gaussians behind it, at the near plane and far off screen
    "three": [(0.0, 0.3, -4.0), (0.5, 0.2, 0.9), (3.0, 0.5, -2.5)],
}


@pytest.mark.parametrize("eyes", sorted(EYES))
def test_projection_forward_matches_reference(eyes):
    means, quats, scales, _, viewmats, Ks = _scene(400, 0, EYES[eyes])
    kw = {"eps2d": 0.3, "near_plane": 0.2, "far_plane": 6.0, "radius_clip": 0.5}
    radii, means2d, depths, conics = cpp_backend.project_gaussians_cpp(
        means, quats, scales, viewmats, Ks, W, H, **kw
    )
    ref = _reference_projection(means, quats, scales, viewmats, Ks, **kw)
    assert radii.dtype == torch.int32 and radii.shape == ref[0].shape
    drawn = ref[0] > 0
    assert drawn.sum() > 50 and (~drawn).sum() > 20  # both kinds occur
    assert torch.equal(radii > 0, drawn)
    assert (radii - ref[0]).abs().max() <= 1  # ceil() of float-equal radii can differ by one ulp's step
    torch.testing.assert_close(means2d[drawn], ref[1][drawn], rtol=1e-5, atol=1e-4)
    torch.testing.assert_close(depths, ref[2], rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(conics[drawn], ref[3][drawn], rtol=2e-4, atol=1e-6)


@pytest.mark.parametrize("eyes", sorted(EYES))
def test_projection_backward_matches_reference(eyes):
    means, quats, scales, _, viewmats, Ks = _scene(300, 1, EYES[eyes])
    g = torch.Generator().manual_seed(7)
    C, N = viewmats.shape[0], means.shape[0]
    v2, vd, vc = (
        torch.randn(C, N, 2, generator=g),
        torch.randn(C, N, generator=g),
        torch.randn(C, N, 3, generator=g),
    )

    def grads(project):
        leaves = [t.clone().requires_grad_(True) for t in (means, quats, scales)]
        radii, means2d, depths, conics = project(*leaves)
        drawn = (radii > 0).float()
        loss = (means2d * v2 * drawn[..., None]).sum() + (depths * vd * drawn).sum()
        loss = loss + (conics * vc * drawn[..., None]).sum()
        return torch.autograd.grad(loss, leaves)

    got = grads(lambda m, q, s: cpp_backend.project_gaussians_cpp(m, q, s, viewmats, Ks, W, H))
    ref = grads(lambda m, q, s: _reference_projection(m, q, s, viewmats, Ks))
    for name, a, b in zip(("means", "quats", "scales"), got, ref, strict=True):
        scale = b.abs().max()
        assert scale > 0, name
        assert (a - b).abs().max() <= 2e-4 * scale, (name, (a - b).abs().max(), scale)


def test_projection_clamped_jacobian_and_tiny_quaternions():
    """Gaussians far outside the field of view (the Jacobian's clamp binds) and near-zero quaternions."""
    viewmats, Ks = _cameras(EYES["one"])
    n = 64
    g = torch.Generator().manual_seed(3)
    means = torch.stack(
        [torch.linspace(-9, 9, n), torch.linspace(-6, 6, n).flip(0), torch.full((n,), 0.5)], -1
    )
    quats = torch.randn(n, 4, generator=g) * torch.logspace(-6, 0, n)[:, None]
    scales = 0.05 + torch.rand(n, 3, generator=g)
    leaves = [t.clone().requires_grad_(True) for t in (means, quats, scales)]
    ref_leaves = [t.clone().requires_grad_(True) for t in (means, quats, scales)]
    out = cpp_backend.project_gaussians_cpp(*leaves, viewmats, Ks, W, H)
    ref = _reference_projection(*ref_leaves, viewmats, Ks)
    drawn = ref[0] > 0
    assert drawn.sum() > 5
    for a, b in ((out, leaves), (ref, ref_leaves)):
        (a[1] * drawn[..., None]).sum().backward(inputs=b, retain_graph=True)
        (a[3][..., 0] * drawn).sum().backward(inputs=b)
    for a, b in zip(leaves, ref_leaves, strict=True):
        torch.testing.assert_close(a.grad, b.grad, rtol=1e-3, atol=1e-5 * b.grad.abs().max().item())


@pytest.mark.parametrize("split", [False, True], ids=["joined", "split"])
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_sh_matches_reference(degree, split):
    """Colours and gradients of the compiled SH kernel equal the reference, with the coefficients
    given joined ``[N, K, 3]`` or split as the model stores them (dc ``[N, 3]``, rest ``[N, K-1, 3]``)."""
    means, _, _, coeffs, viewmats, _ = _scene(300, 2, EYES["three"])
    C, N = viewmats.shape[0], means.shape[0]
    radii = (torch.rand(C, N, generator=torch.Generator().manual_seed(4)) > 0.3).int()
    v = torch.randn(C, N, 3, generator=torch.Generator().manual_seed(5))
    m1, m2 = means.clone().requires_grad_(True), means.clone().requires_grad_(True)
    c2 = coeffs.clone().requires_grad_(True)
    if split:
        dc, rest = coeffs[:, 0].clone().requires_grad_(True), coeffs[:, 1:].clone().requires_grad_(True)
        colors = cpp_backend.sh_colors_cpp(m1, viewmats, (dc, rest), degree, radii)
    else:
        c1 = coeffs.clone().requires_grad_(True)
        colors = cpp_backend.sh_colors_cpp(m1, viewmats, c1, degree, radii)
    campos = torch.linalg.inv(viewmats)[:, :3, 3]
    ref = torch.clamp_min(
        spherical_harmonics(degree, m2[None] - campos[:, None], c2[None].expand(C, -1, -1, -1)) + 0.5, 0
    )
    drawn = radii > 0
    assert (ref == 0).any() or degree == 0  # the clamp at 0 is exercised
    torch.testing.assert_close(colors[drawn], ref[drawn], rtol=1e-5, atol=1e-6)
    assert (colors[~drawn] == 0).all()
    (colors * v).sum().backward()
    (ref * v * drawn[..., None]).sum().backward()
    coeff_grad = torch.cat((dc.grad[:, None], rest.grad), dim=1) if split else c1.grad
    torch.testing.assert_close(coeff_grad, c2.grad, rtol=1e-4, atol=1e-5)
    if degree == 0:  # a constant colour: no gradient for the means
        assert m2.grad is None and not m1.grad.any()
    else:
        torch.testing.assert_close(m1.grad, m2.grad, rtol=1e-3, atol=1e-5 * m2.grad.abs().max().item())
    if degree < 3:
        assert (coeff_grad[:, (degree + 1) ** 2 :] == 0).all()


@pytest.mark.parametrize("backend", ["cpp", "torch"])
def test_rasterization_takes_split_sh_coefficients(backend):
    """``colors=(dc, rest)`` renders and differentiates exactly as the joined ``[N, K, 3]`` tensor."""
    from stealth_ns.raster import rasterization

    means, quats, scales, coeffs, viewmats, Ks = _scene(200, 4, EYES["three"][:1], spread=1.0)
    opac = torch.full((means.shape[0],), 0.6)
    joined = coeffs.clone().requires_grad_(True)
    dc, rest = coeffs[:, 0].clone().requires_grad_(True), coeffs[:, 1:].clone().requires_grad_(True)
    outs = []
    for colors in (joined, (dc, rest)):
        img, alpha, _ = rasterization(
            means, quats, scales, opac, colors, viewmats, Ks, W, H, sh_degree=3, backend=backend
        )
        (img.square().sum() + alpha.sum()).backward()
        outs.append(img.detach())
    assert outs[0].abs().sum() > 0
    torch.testing.assert_close(outs[1], outs[0], rtol=0, atol=0)
    torch.testing.assert_close(torch.cat((dc.grad[:, None], rest.grad), dim=1), joined.grad, rtol=0, atol=0)


def test_rasterization_uses_the_compiled_projection_with_reference_gradients():
    """The whole CPU pipeline, compiled projection vs the reference projection (both with the compiled
    rasterizer): images and every parameter's gradient agree."""
    from stealth_ns.raster import rasterization

    means, quats, scales, coeffs, viewmats, Ks = _scene(
        500, 6, EYES["three"][:1] + EYES["three"][2:], spread=1.0
    )
    opac = torch.full((means.shape[0],), 0.6)

    def run(camera_grad: bool):
        leaves = [t.clone().requires_grad_(True) for t in (means, quats, scales, opac, coeffs)]
        vm = viewmats.clone().requires_grad_(camera_grad)  # a camera gradient selects the reference path
        img, alpha, info = rasterization(
            *leaves, vm, Ks, W, H, sh_degree=3, backend="cpp", render_mode="RGB+ED"
        )
        (img.square().sum() + alpha.sum()).backward()
        return img.detach(), [t.grad for t in leaves]

    img, grads = run(camera_grad=False)
    ref_img, ref_grads = run(camera_grad=True)
    torch.testing.assert_close(img, ref_img, rtol=1e-4, atol=1e-4)
    for got, ref in zip(grads, ref_grads, strict=True):
        assert (got - ref).abs().max() <= 1e-3 * ref.abs().max()


def test_bad_inputs_raise():
    means, quats, scales, coeffs, viewmats, Ks = _scene(10, 0, EYES["one"])
    ext = cpp_backend.load_extension()
    with pytest.raises(RuntimeError, match="quats must be"):
        ext.project_fwd(means, quats[:, :3].contiguous(), scales, viewmats, Ks, W, H, 0.3, 0.01, 1e10, 0.0)
    radii = torch.ones(1, 10, dtype=torch.int32)
    with pytest.raises(RuntimeError, match="needs 16 coefficients"):
        ext.sh_fwd(means, viewmats, coeffs[:, 0].contiguous(), coeffs[:, 1:9].contiguous(), 3, radii)
