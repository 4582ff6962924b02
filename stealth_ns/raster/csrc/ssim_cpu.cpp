// SSIM (Gaussian window, valid convolution) and its gradient with respect to the second image, on the CPU.
//
// The readable reference with the same contract is pytorch_msssim's `ssim` (what splatfacto's loss calls):
//   mu = G * I, sigma_xx = G * (X X) - mu_x^2, ..., with G the separable 1-D window applied along H, then W,
//   no padding; S = (2 mu_x mu_y + C1)(2 sigma_xy + C2) / ((mu_x^2 + mu_y^2 + C1)(sigma_xx + sigma_yy + C2));
//   one value per (image, channel) plane: the mean of S over the valid H' x W' window positions.
// The forward keeps dS/d(mu_y), dS/d(E[YY]), dS/d(E[XY]) per window position; the backward scales them by
// the upstream gradient of each plane and takes them back through the transposed window:
//   dL/dY = G^T g_mu + 2 Y G^T g_yy + X G^T g_xy.
// Both passes are fused row by row (each output row's five maps are filtered down the window's rows and
// then along the row, in L1; the backward likewise), one task per block of ROWS output rows of a plane,
// and every sum keeps the order of the unfused filters (down the rows, then along them; the transposed
// filters in reverse), so the values are bitwise those of filtering whole maps. Each plane's SSIM is
// summed in window order by one task: deterministic whatever the thread count.

#include "ssim_cpu.h"
#include "tensor_checks.h"

#include <ATen/Parallel.h>
#include <ATen/ops/empty.h>
#include <ATen/ops/empty_like.h>

#include <algorithm>
#include <vector>

namespace stealth_ns {
namespace {

void check_image(const at::Tensor &t, const char *name) {
    check_cpu_f32(t, name);
    TORCH_CHECK(t.dim() == 4, name, " must be [B, C, H, W]");
}

// out[x] = sum_k w[k] in[x + k]: one row of W -> W - K + 1 (the sum starts at 0, k in order)
void filter_row(const float *in, int64_t W, const float *w, int64_t K, float *out) {
    const int64_t Wo = W - K + 1;
    for (int64_t x = 0; x < Wo; ++x) out[x] = 0.0f;
    for (int64_t k = 0; k < K; ++k) {
        const float wk = w[k];
        for (int64_t x = 0; x < Wo; ++x) out[x] += wk * in[x + k];
    }
}

// Transpose of filter_row: one row of Wo -> Wo + K - 1
void filter_row_t(const float *in, int64_t Wo, const float *w, int64_t K, float *out) {
    const int64_t W = Wo + K - 1;
    for (int64_t x = 0; x < W; ++x) out[x] = 0.0f;
    for (int64_t k = 0; k < K; ++k) {
        const float wk = w[k];
        for (int64_t x = 0; x < Wo; ++x) out[x + k] += wk * in[x];
    }
}

// One row of the window down the image rows: col[q * W + i] += w_k * (mu_x, mu_y, E[XX], E[YY], E[XY])
// terms of the image row (rx, ry). The arguments are __restrict__ so that GCC vectorises the loop (with
// the pointers as locals it would need more run-time overlap checks than it makes, and stays scalar).
void window_row(const float *__restrict__ rx, const float *__restrict__ ry, int64_t W, float wk,
                float *__restrict__ col) {
    float *__restrict__ c0 = col, *__restrict__ c1 = col + W, *__restrict__ c2 = col + 2 * W;
    float *__restrict__ c3 = col + 3 * W, *__restrict__ c4 = col + 4 * W;
    for (int64_t i = 0; i < W; ++i) {
        const float a = rx[i], b = ry[i];
        c0[i] += wk * a;
        c1[i] += wk * b;
        c2[i] += wk * (a * a);
        c3[i] += wk * (b * b);
        c4[i] += wk * (a * b);
    }
}

// The SSIM map S of one row of window positions from its five filtered maps m [5, Wo] into s [Wo], and
// with G the derivatives dS/dmu_y, dS/dE[YY], dS/dE[XY] (divided by n) into g, g + HWo, g + 2 HWo.
template <bool G>
void ssim_row(const float *__restrict__ m, int64_t Wo, float c1, float c2, float inv_n, float *__restrict__ s,
              float *__restrict__ g, int64_t HWo) {
    float *__restrict__ g1 = G ? g + HWo : nullptr, *__restrict__ g2 = G ? g + 2 * HWo : nullptr;
    for (int64_t i = 0; i < Wo; ++i) {
        const float mx = m[i], my = m[Wo + i];
        const float sxx = m[2 * Wo + i] - mx * mx, syy = m[3 * Wo + i] - my * my;
        const float sxy = m[4 * Wo + i] - mx * my;
        const float A = 2.0f * mx * my + c1, B = mx * mx + my * my + c1;
        const float Cn = 2.0f * sxy + c2, D = sxx + syy + c2;
        const float S = (A * Cn) / (B * D);
        s[i] = S;
        if (G) {
            g[i] = (2.0f * mx * (Cn - A) / (B * D) - 2.0f * my * S / B + 2.0f * my * S / D) * inv_n;
            g1[i] = (-S / D) * inv_n;
            g2[i] = (2.0f * A / (B * D)) * inv_n;
        }
    }
}

constexpr int64_t ROWS = 32;  // output rows per task: the backward recomputes K - 1 filtered rows per task

struct Dims {
    int64_t planes, H, W, K, Ho, Wo;
};

Dims check(const at::Tensor &X, const at::Tensor &Y, const at::Tensor &win) {
    check_image(X, "X");
    check_image(Y, "Y");
    TORCH_CHECK(X.sizes() == Y.sizes(), "X and Y must have the same shape");
    check_cpu_f32(win, "win");
    TORCH_CHECK(win.dim() == 1, "win must be a vector");
    const int64_t K = win.size(0), H = X.size(2), W = X.size(3);
    TORCH_CHECK(H >= K && W >= K, "the image (", H, " x ", W, ") is smaller than the window (", K, ")");
    return {X.size(0) * X.size(1), H, W, K, H - K + 1, W - K + 1};
}

}  // namespace

std::vector<at::Tensor> ssim_fwd(const at::Tensor &X, const at::Tensor &Y, const at::Tensor &win,
                                 double C1, double C2, bool need_grad) {
    const Dims d = check(X, Y, win);
    const int64_t HW = d.H * d.W, HWo = d.Ho * d.Wo, W = d.W, K = d.K;
    auto planes = at::empty({X.size(0), X.size(1)}, X.options());
    // per plane: dS/dmu_y, dS/dE[YY], dS/dE[XY], already divided by the number of window positions
    auto dmaps = need_grad ? at::empty({d.planes, 3, d.Ho, d.Wo}, X.options()) : at::empty({0}, X.options());
    auto smap = at::empty({d.planes, HWo}, X.options());  // S per window position, summed in order below
    const float *xp = X.data_ptr<float>(), *yp = Y.data_ptr<float>(), *w = win.data_ptr<float>();
    float *pp = planes.data_ptr<float>(), *sp = smap.data_ptr<float>();
    float *dp = need_grad ? dmaps.data_ptr<float>() : nullptr;
    const float c1 = (float)C1, c2 = (float)C2, inv_n = 1.0f / (float)HWo;
    const int64_t blocks = (d.Ho + ROWS - 1) / ROWS;
    at::parallel_for(0, d.planes * blocks, 1, [&](int64_t begin, int64_t end) {
        // the five maps of one output row, filtered down the rows (W) and then along them (Wo)
        std::vector<float> col((size_t)5 * W), m((size_t)5 * d.Wo);
        for (int64_t task = begin; task < end; ++task) {
            const int64_t p = task / blocks, y0 = (task % blocks) * ROWS, y1 = std::min(d.Ho, y0 + ROWS);
            const float *x = xp + p * HW, *yy = yp + p * HW;
            for (int64_t r = y0; r < y1; ++r) {
                for (int64_t i = 0; i < 5 * W; ++i) col[i] = 0.0f;
                for (int64_t k = 0; k < K; ++k) window_row(x + (r + k) * W, yy + (r + k) * W, W, w[k], col.data());
                for (int q = 0; q < 5; ++q) filter_row(col.data() + q * W, W, w, K, m.data() + q * d.Wo);
                const int64_t o = r * d.Wo;
                if (dp)
                    ssim_row<true>(m.data(), d.Wo, c1, c2, inv_n, sp + p * HWo + o, dp + p * 3 * HWo + o, HWo);
                else
                    ssim_row<false>(m.data(), d.Wo, c1, c2, inv_n, sp + p * HWo + o, nullptr, HWo);
            }
        }
    });
    at::parallel_for(0, d.planes, 1, [&](int64_t begin, int64_t end) {
        for (int64_t p = begin; p < end; ++p) {
            double total = 0.0;  // in window order, one plane per task: the same sum for any thread count
            for (int64_t i = 0; i < HWo; ++i) total += sp[p * HWo + i];
            pp[p] = (float)(total / (double)HWo);
        }
    });
    return {planes, dmaps};
}

at::Tensor ssim_bwd(const at::Tensor &X, const at::Tensor &Y, const at::Tensor &win,
                    const at::Tensor &dmaps, const at::Tensor &v_planes) {
    const Dims d = check(X, Y, win);
    const int64_t HW = d.H * d.W, HWo = d.Ho * d.Wo, W = d.W, K = d.K;
    check_cpu_f32(dmaps, "dmaps");
    check_cpu_f32(v_planes, "v_planes");
    TORCH_CHECK(dmaps.numel() == d.planes * 3 * HWo, "dmaps must be [planes, 3, H', W']");
    TORCH_CHECK(v_planes.numel() == d.planes, "v_planes must be [B, C]");
    auto v_Y = at::empty_like(Y);
    const float *xp = X.data_ptr<float>(), *yp = Y.data_ptr<float>(), *w = win.data_ptr<float>();
    const float *dp = dmaps.data_ptr<float>(), *vp = v_planes.data_ptr<float>();
    float *out = v_Y.data_ptr<float>();
    const int64_t blocks = (d.H + ROWS - 1) / ROWS;
    at::parallel_for(0, d.planes * blocks, 1, [&](int64_t begin, int64_t end) {
        // G^T (v dS/dmu_y), G^T (v dS/dE[YY]), G^T (v dS/dE[XY]): each map's rows taken back along W
        // (rows r0..r1-1, those the task's output rows gather), then down the rows, row by row
        std::vector<float> g((size_t)d.Wo), t((size_t)3 * (ROWS + K - 1) * W), back((size_t)3 * W);
        for (int64_t task = begin; task < end; ++task) {
            const int64_t p = task / blocks, Y0 = (task % blocks) * ROWS, Y1 = std::min(d.H, Y0 + ROWS);
            const int64_t r0 = std::max<int64_t>(0, Y0 - K + 1), r1 = std::min(d.Ho, Y1);
            const int64_t n = r1 - r0;
            for (int q = 0; q < 3; ++q)
                for (int64_t r = r0; r < r1; ++r) {
                    const float *src = dp + (p * 3 + q) * HWo + r * d.Wo;
                    for (int64_t i = 0; i < d.Wo; ++i) g[i] = vp[p] * src[i];
                    filter_row_t(g.data(), d.Wo, w, K, t.data() + (q * n + (r - r0)) * W);
                }
            const float *x = xp + p * HW, *yy = yp + p * HW;
            for (int64_t Yr = Y0; Yr < Y1; ++Yr) {
                // rows r with r <= Yr < r + K, in increasing r (the order the transposed filter adds them)
                const int64_t lo = std::max<int64_t>(0, Yr - K + 1), hi = std::min(d.Ho - 1, Yr);
                for (int q = 0; q < 3; ++q) {
                    float *b = back.data() + q * W;
                    for (int64_t i = 0; i < W; ++i) b[i] = 0.0f;
                    for (int64_t r = lo; r <= hi; ++r) {
                        const float wk = w[Yr - r];
                        const float *tr = t.data() + (q * n + (r - r0)) * W;
                        for (int64_t i = 0; i < W; ++i) b[i] += wk * tr[i];
                    }
                }
                const float *b0 = back.data(), *b1 = b0 + W, *b2 = b1 + W;
                const float *xr = x + Yr * W, *yr = yy + Yr * W;
                float *o = out + p * HW + Yr * W;
                for (int64_t i = 0; i < W; ++i) o[i] = b0[i] + 2.0f * yr[i] * b1[i] + xr[i] * b2[i];
            }
        }
    });
    return v_Y;
}

}  // namespace stealth_ns
