// SSIM of two image batches and its gradient with respect to the second, on the CPU (see ssim_cpu.cpp).
#pragma once

#include <ATen/core/Tensor.h>

#include <vector>

namespace stealth_ns {

// (per-plane SSIM [B, C], and when need_grad the per-plane derivative maps [B*C, 3, H', W'] for ssim_bwd)
std::vector<at::Tensor> ssim_fwd(const at::Tensor &X, const at::Tensor &Y, const at::Tensor &win,
                                 double C1, double C2, bool need_grad);

// dL/dY [B, C, H, W] ([B, H, W, C] when channels_last) from the upstream gradient of the per-plane SSIM
// v_planes [B, C], plus -(l1_coef sgn(X - Y)): the gradient of the L1 term of a loss
// w |X - Y|.mean() + ..., l1_coef = w / numel (0: none)
at::Tensor ssim_bwd(const at::Tensor &X, const at::Tensor &Y, const at::Tensor &win,
                    const at::Tensor &dmaps, const at::Tensor &v_planes, double l1_coef, bool channels_last);

}  // namespace stealth_ns
