"""The compiled SSIM (training loss) against its reference, pytorch_msssim."""

import pytest
import torch
from pytorch_msssim import SSIM as ReferenceSSIM

from stealth_ns.images.ssim import SSIM, l1_ssim_loss
from stealth_ns.raster import cpp_backend

pytestmark = pytest.mark.skipif(
    cpp_backend.load_extension() is None, reason="compiled CPU module unavailable"
)


def _images(shape, seed=0):
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(shape, generator=g)
    y = (x + 0.2 * torch.randn(shape, generator=g)).clamp(0, 1)  # correlated, as a render and its target
    return x, y


@pytest.mark.parametrize("shape", [(1, 3, 96, 128), (2, 3, 23, 41), (1, 3, 11, 11)])
@pytest.mark.parametrize("size_average", [True, False])
def test_value_and_gradient_match_pytorch_msssim(shape, size_average):
    x, y = _images(shape)
    ours, ref = (
        SSIM(data_range=1.0, size_average=size_average, channel=3),
        ReferenceSSIM(data_range=1.0, size_average=size_average, channel=3),
    )
    y1, y2 = y.clone().requires_grad_(True), y.clone().requires_grad_(True)
    assert ours._compiled_path(x, y1)
    a, b = ours(x, y1), ref(x, y2)
    torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)
    w = torch.linspace(0.5, 1.5, a.numel()).reshape(a.shape)  # a non-uniform upstream gradient
    (1 - a * w).sum().backward()
    (1 - b * w).sum().backward()
    assert y2.grad.abs().max() > 0
    torch.testing.assert_close(y1.grad, y2.grad, rtol=1e-4, atol=1e-5 * y2.grad.abs().max().item())


def _whole_map_ssim(x, y, win, C1, C2):
    """Per-plane SSIM and its gradient filtered as whole maps, in the kernel's summation order (each
    sum starts at 0 and adds the window taps in order; the transposed filters add the rows in order):
    the fused row-by-row kernel must give exactly these bits."""
    K = win.numel()

    def filt_h(m):  # down the rows
        out = torch.zeros(m.shape[0] - K + 1, m.shape[1])
        for k in range(K):
            out = out + win[k] * m[k : k + out.shape[0]]
        return out

    def filt_w(m):  # along the rows
        out = torch.zeros(m.shape[0], m.shape[1] - K + 1)
        for k in range(K):
            out = out + win[k] * m[:, k : k + out.shape[1]]
        return out

    planes = []
    for X, Y in zip(x.reshape(-1, *x.shape[2:]), y.reshape(-1, *y.shape[2:]), strict=True):
        mx, my, exx, eyy, exy = (filt_w(filt_h(m)) for m in (X, Y, X * X, Y * Y, X * Y))
        sxx, syy, sxy = exx - mx * mx, eyy - my * my, exy - mx * my
        S = ((2 * mx * my + C1) * (2 * sxy + C2)) / ((mx * mx + my * my + C1) * (sxx + syy + C2))
        planes.append(S.double().flatten().cumsum(0)[-1] / S.numel())  # double sum in window order
    return torch.stack(planes).float()


@pytest.mark.parametrize("shape", [(1, 3, 75, 50), (1, 2, 33, 12), (1, 3, 150, 37), (2, 3, 40, 24)])
def test_fused_kernel_gives_the_bits_of_whole_map_filters_for_any_thread_count(shape):
    """Rows are filtered in blocks of 64 per task (heights not a multiple of it, a block of one output
    row, three blocks; the planes' sums four at a time and the two left): the values are those of
    filtering whole maps, with 1 or 2 threads."""
    from pytorch_msssim.ssim import _fspecial_gauss_1d

    ext = cpp_backend.load_extension()
    x, y = _images(shape)
    win = _fspecial_gauss_1d(11, 1.5).reshape(-1).contiguous()
    expected = _whole_map_ssim(x, y, win, 1e-4, 9e-4).reshape(shape[:2])
    threads = torch.get_num_threads()
    results = []
    try:
        for n in (1, 2):
            torch.set_num_threads(n)
            planes, dmaps = ext.ssim_fwd(x, y, win, 1e-4, 9e-4, True)
            v_planes = torch.linspace(0.5, 1.5, shape[0] * shape[1]).reshape(shape[:2])
            v_y = ext.ssim_bwd(x, y, win, dmaps, v_planes)
            results.append((planes, v_y))
    finally:
        torch.set_num_threads(threads)
    torch.testing.assert_close(results[0][0], expected, rtol=0, atol=0)
    assert torch.equal(results[0][0], results[1][0]) and torch.equal(results[0][1], results[1][1])


def test_identical_images_give_one_and_no_gradient_step():
    x, _ = _images((1, 3, 30, 30))
    y = x.clone().requires_grad_(True)
    value = SSIM(data_range=1.0, channel=3)(x, y)
    assert value.item() == pytest.approx(1.0, abs=1e-5)
    value.backward()
    assert y.grad.abs().max() < 1e-4  # SSIM is maximal at Y = X


def test_falls_back_to_the_reference_where_the_kernel_does_not_apply():
    ours = SSIM(data_range=1.0, channel=3)
    x, y = _images((1, 3, 8, 40))  # smaller than the window: pytorch_msssim skips that dimension
    assert not ours._compiled_path(x, y)
    with pytest.warns(UserWarning, match="Skipping Gaussian Smoothing"):
        torch.testing.assert_close(ours(x, y), ReferenceSSIM(data_range=1.0, channel=3)(x, y))
    x2, y2 = _images((1, 3, 20, 20))
    assert not ours._compiled_path(x2.requires_grad_(True), y2)  # a gradient for X: the reference
    assert not ours._compiled_path(x2.double(), y2.double())


def test_kernel_rejects_bad_inputs():
    ext = cpp_backend.load_extension()
    x, y = _images((1, 3, 20, 20))
    win = torch.ones(11) / 11
    with pytest.raises(RuntimeError, match="smaller than the window"):
        ext.ssim_fwd(x[..., :10].contiguous(), y[..., :10].contiguous(), win, 1e-4, 9e-4, False)
    with pytest.raises(RuntimeError, match="same shape"):
        ext.ssim_fwd(x, y[:, :2].contiguous(), win, 1e-4, 9e-4, False)


def test_gradient_of_a_permuted_hwc_image_comes_back_in_its_layout():
    """The training loss permutes [H, W, 3] images to [1, 3, H, W]: the gradient keeps that memory
    layout (a contiguous [H, W, 3] gradient downstream), with the same values as for a copy."""
    x, y = _images((1, 3, 31, 45), seed=3)
    ssim = SSIM(data_range=1.0, size_average=True, channel=3)
    hwc = y[0].permute(1, 2, 0).contiguous().requires_grad_(True)
    planes = y.clone().requires_grad_(True)
    ssim(x, hwc.permute(2, 0, 1)[None]).backward()
    ssim(x, planes).backward()
    assert hwc.grad.is_contiguous()
    assert torch.equal(hwc.grad, planes.grad[0].permute(1, 2, 0))


def _splatfacto_main_loss(pred, gt, ssim, lam):
    """splatfacto's get_loss_dict main loss, op for op."""
    l1 = torch.abs(gt - pred).mean()
    return (1 - lam) * l1 + lam * (1 - ssim(gt.permute(2, 0, 1)[None], pred.permute(2, 0, 1)[None]))


@pytest.mark.parametrize(
    ("H", "W", "lam", "upstream"), [(37, 53, 0.2, 1.0), (96, 128, 0.2, 0.37), (11, 19, 0.9, 2.0)]
)
def test_fused_l1_ssim_loss_gives_the_bits_of_autograd(H, W, lam, upstream):
    """The fused loss: the same loss value, and the same gradient, through the composite before it, as
    autograd of splatfacto's expression; equal pixels (sgn 0) included."""
    x, y = _images((1, 3, H, W), seed=H)
    gt, render = x[0].permute(1, 2, 0).contiguous(), y[0].permute(1, 2, 0).contiguous()
    render[:2] = gt[:2]
    alpha = torch.rand(H, W, 1, generator=torch.Generator().manual_seed(1))
    bg = torch.tensor([0.1, 0.6, 0.3])
    ssim = SSIM(data_range=1.0, size_average=True, channel=3)
    results = []
    for fused in (True, False):
        r, a = render.clone().requires_grad_(True), alpha.clone().requires_grad_(True)
        pred = torch.clamp(r + (1 - a) * bg, 0.0, 1.0)
        loss = l1_ssim_loss(pred, gt, ssim, lam) if fused else _splatfacto_main_loss(pred, gt, ssim, lam)
        (loss * upstream).backward()
        results.append((loss.detach(), r.grad, a.grad))
    for ours, theirs in zip(*results, strict=True):
        assert torch.equal(ours, theirs)
    assert results[0][1].abs().max() > 0


def test_fused_l1_ssim_loss_only_where_the_kernel_applies():
    ssim = SSIM(data_range=1.0, size_average=True, channel=3)
    gt, pred = torch.rand(20, 30, 3), torch.rand(20, 30, 3)
    assert l1_ssim_loss(pred, gt, ssim, 0.2) is not None
    assert l1_ssim_loss(pred, gt.requires_grad_(True), ssim, 0.2) is None  # the target needs no gradient
    assert l1_ssim_loss(pred[:8], gt[:8].detach(), ssim, 0.2) is None  # smaller than the window
    assert l1_ssim_loss(pred.double(), gt.detach().double(), ssim, 0.2) is None
    assert l1_ssim_loss(pred, gt.detach(), SSIM(data_range=1.0, size_average=False, channel=3), 0.2) is None
