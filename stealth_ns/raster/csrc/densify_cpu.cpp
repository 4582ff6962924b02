// Densification statistics of one training step (gsplat 1.4.0 DefaultStrategy._update_state, unpacked).
//
// The readable reference with the same contract is stealth_ns/method/densification.py's
// `accumulate_statistics` (masked torch operations over the [C, N] grid), itself checked bitwise against
// gsplat's. One pass over the Gaussians replaces its dozen full-size temporaries (a clone of the
// gradients, two scalings, the norm, a `where` per camera, ...).
//
// Every value is rounded as torch rounds it: the gradient is scaled in float, and its norm is torch's
// float reduction over the last dimension, sqrt(fma(y, y, x * x)) (this file is compiled with
// -ffp-contract=off, so the one fused multiply-add is the explicit one); radii / size is a float
// division. The cameras are visited in order, so with several cameras the sums are added in torch's
// order. Each Gaussian is one task's: deterministic whatever the thread count.

#include "densify_cpu.h"
#include "tensor_checks.h"

#include <ATen/Parallel.h>

#include <cmath>

namespace stealth_ns {

void densify_stats(at::Tensor &grad2d, at::Tensor &count, const std::optional<at::Tensor> &max_radii,
                   const at::Tensor &grads, const at::Tensor &radii, double scale_x, double scale_y,
                   double size) {
    check_cpu_f32(grads, "grads");
    check_cpu_i32(radii, "radii");
    TORCH_CHECK(grads.dim() == 3 && grads.size(2) == 2, "grads must be [C, N, 2]");
    const int64_t C = grads.size(0), N = grads.size(1);
    TORCH_CHECK(radii.dim() == 2 && radii.size(0) == C && radii.size(1) == N, "radii must be [C, N]");
    check_cpu_f32(grad2d, "grad2d");
    check_cpu_f32(count, "count");
    TORCH_CHECK(grad2d.numel() == N && count.numel() == N, "grad2d and count must have N values");
    float *kept = nullptr;
    if (max_radii.has_value()) {
        check_cpu_f32(*max_radii, "max_radii");
        TORCH_CHECK(max_radii->numel() == N, "max_radii must have N values");
        kept = max_radii->data_ptr<float>();
    }
    const float sx = (float)scale_x, sy = (float)scale_y, fsize = (float)size;
    const float *g = grads.data_ptr<float>();
    const int32_t *r = radii.data_ptr<int32_t>();
    float *sum = grad2d.data_ptr<float>(), *cnt = count.data_ptr<float>();
    at::parallel_for(0, N, 4096, [&](int64_t begin, int64_t end) {
        for (int64_t n = begin; n < end; ++n) {
            const float before = kept ? kept[n] : 0.0f;
            for (int64_t c = 0; c < C; ++c) {
                const int32_t rad = r[c * N + n];
                if (rad <= 0) continue;
                const float x = g[2 * (c * N + n)] * sx, y = g[2 * (c * N + n) + 1] * sy;
                sum[n] += std::sqrt(std::fma(y, y, x * x));
                cnt[n] += 1.0f;
                if (kept) {
                    const float rel = (float)rad / fsize;
                    kept[n] = std::isnan(before) || before >= rel ? before : rel;  // torch.maximum
                }
            }
        }
    });
}

}  // namespace stealth_ns
