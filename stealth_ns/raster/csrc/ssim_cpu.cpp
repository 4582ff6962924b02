// SSIM (Gaussian window, valid convolution) and its gradient with respect to the second image, on the CPU.
//
// The readable reference with the same contract is pytorch_msssim's `ssim` (what splatfacto's loss calls):
//   mu = G * I, sigma_xx = G * (X X) - mu_x^2, ..., with G the separable 1-D window applied along H, then W,
//   no padding; S = (2 mu_x mu_y + C1)(2 sigma_xy + C2) / ((mu_x^2 + mu_y^2 + C1)(sigma_xx + sigma_yy + C2));
//   one value per (image, channel) plane: the mean of S over the valid H' x W' window positions.
// The forward keeps dS/d(mu_y), dS/d(E[YY]), dS/d(E[XY]) per window position; the backward scales them by
// the upstream gradient of each plane and takes them back through the transposed window:
//   dL/dY = G^T g_mu + 2 Y G^T g_yy + X G^T g_xy.
// One task per plane (a plane's sums run in a fixed order: deterministic whatever the thread count).

#include "ssim_cpu.h"
#include "tensor_checks.h"

#include <ATen/Parallel.h>
#include <ATen/ops/empty.h>
#include <ATen/ops/empty_like.h>

#include <vector>

namespace stealth_ns {
namespace {

void check_image(const at::Tensor &t, const char *name) {
    check_cpu_f32(t, name);
    TORCH_CHECK(t.dim() == 4, name, " must be [B, C, H, W]");
}

// out[y][x] = sum_k w[k] in[y + k][x]: [H, W] -> [H - K + 1, W]
void filter_h(const float *in, int64_t H, int64_t W, const float *w, int64_t K, float *out) {
    const int64_t Ho = H - K + 1;
    for (int64_t y = 0; y < Ho; ++y) {
        float *o = out + y * W;
        for (int64_t x = 0; x < W; ++x) o[x] = 0.0f;
        for (int64_t k = 0; k < K; ++k) {
            const float *r = in + (y + k) * W;
            const float wk = w[k];
            for (int64_t x = 0; x < W; ++x) o[x] += wk * r[x];
        }
    }
}

// out[y][x] = sum_k w[k] in[y][x + k]: [H, W] -> [H, W - K + 1]
void filter_w(const float *in, int64_t H, int64_t W, const float *w, int64_t K, float *out) {
    const int64_t Wo = W - K + 1;
    for (int64_t y = 0; y < H; ++y) {
        float *o = out + y * Wo;
        const float *r = in + y * W;
        for (int64_t x = 0; x < Wo; ++x) o[x] = 0.0f;
        for (int64_t k = 0; k < K; ++k) {
            const float wk = w[k];
            for (int64_t x = 0; x < Wo; ++x) o[x] += wk * r[x + k];
        }
    }
}

// Transpose of filter_w: [H, Wo] -> [H, Wo + K - 1]
void filter_w_t(const float *in, int64_t H, int64_t Wo, const float *w, int64_t K, float *out) {
    const int64_t W = Wo + K - 1;
    for (int64_t y = 0; y < H; ++y) {
        float *o = out + y * W;
        const float *r = in + y * Wo;
        for (int64_t x = 0; x < W; ++x) o[x] = 0.0f;
        for (int64_t k = 0; k < K; ++k) {
            const float wk = w[k];
            for (int64_t x = 0; x < Wo; ++x) o[x + k] += wk * r[x];
        }
    }
}

// Transpose of filter_h: [Ho, W] -> [Ho + K - 1, W]
void filter_h_t(const float *in, int64_t Ho, int64_t W, const float *w, int64_t K, float *out) {
    const int64_t H = Ho + K - 1;
    for (int64_t i = 0; i < H * W; ++i) out[i] = 0.0f;
    for (int64_t y = 0; y < Ho; ++y) {
        const float *r = in + y * W;
        for (int64_t k = 0; k < K; ++k) {
            float *o = out + (y + k) * W;
            const float wk = w[k];
            for (int64_t x = 0; x < W; ++x) o[x] += wk * r[x];
        }
    }
}

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
    const int64_t HW = d.H * d.W, HWo = d.Ho * d.Wo;
    auto planes = at::empty({X.size(0), X.size(1)}, X.options());
    // per plane: dS/dmu_y, dS/dE[YY], dS/dE[XY], already divided by the number of window positions
    auto dmaps = need_grad ? at::empty({d.planes, 3, d.Ho, d.Wo}, X.options()) : at::empty({0}, X.options());
    const float *xp = X.data_ptr<float>(), *yp = Y.data_ptr<float>(), *w = win.data_ptr<float>();
    float *pp = planes.data_ptr<float>();
    float *dp = need_grad ? dmaps.data_ptr<float>() : nullptr;
    const float c1 = (float)C1, c2 = (float)C2, inv_n = 1.0f / (float)HWo;
    at::parallel_for(0, d.planes, 1, [&](int64_t begin, int64_t end) {
        std::vector<float> src((size_t)HW), tmp((size_t)d.Ho * d.W), m((size_t)5 * HWo);
        for (int64_t p = begin; p < end; ++p) {
            const float *x = xp + p * HW, *y = yp + p * HW;
            for (int q = 0; q < 5; ++q) {  // mu_x, mu_y, E[XX], E[YY], E[XY]
                const float *s = q == 0 ? x : (q == 1 ? y : src.data());
                if (q >= 2)
                    for (int64_t i = 0; i < HW; ++i)
                        src[i] = q == 2 ? x[i] * x[i] : (q == 3 ? y[i] * y[i] : x[i] * y[i]);
                filter_h(s, d.H, d.W, w, d.K, tmp.data());
                filter_w(tmp.data(), d.Ho, d.W, w, d.K, m.data() + q * HWo);
            }
            double total = 0.0;
            for (int64_t i = 0; i < HWo; ++i) {
                const float mx = m[i], my = m[HWo + i];
                const float sxx = m[2 * HWo + i] - mx * mx, syy = m[3 * HWo + i] - my * my;
                const float sxy = m[4 * HWo + i] - mx * my;
                const float A = 2.0f * mx * my + c1, B = mx * mx + my * my + c1;
                const float Cn = 2.0f * sxy + c2, D = sxx + syy + c2;
                const float S = (A * Cn) / (B * D);
                total += S;
                if (dp) {
                    float *g = dp + p * 3 * HWo;
                    g[i] = (2.0f * mx * (Cn - A) / (B * D) - 2.0f * my * S / B + 2.0f * my * S / D) * inv_n;
                    g[HWo + i] = (-S / D) * inv_n;
                    g[2 * HWo + i] = (2.0f * A / (B * D)) * inv_n;
                }
            }
            pp[p] = (float)(total / (double)HWo);
        }
    });
    return {planes, dmaps};
}

at::Tensor ssim_bwd(const at::Tensor &X, const at::Tensor &Y, const at::Tensor &win,
                    const at::Tensor &dmaps, const at::Tensor &v_planes) {
    const Dims d = check(X, Y, win);
    const int64_t HW = d.H * d.W, HWo = d.Ho * d.Wo;
    check_cpu_f32(dmaps, "dmaps");
    check_cpu_f32(v_planes, "v_planes");
    TORCH_CHECK(dmaps.numel() == d.planes * 3 * HWo, "dmaps must be [planes, 3, H', W']");
    TORCH_CHECK(v_planes.numel() == d.planes, "v_planes must be [B, C]");
    auto v_Y = at::empty_like(Y);
    const float *xp = X.data_ptr<float>(), *yp = Y.data_ptr<float>(), *w = win.data_ptr<float>();
    const float *dp = dmaps.data_ptr<float>(), *vp = v_planes.data_ptr<float>();
    float *out = v_Y.data_ptr<float>();
    at::parallel_for(0, d.planes, 1, [&](int64_t begin, int64_t end) {
        std::vector<float> g((size_t)HWo), tmp((size_t)d.Ho * d.W), back((size_t)3 * HW);
        for (int64_t p = begin; p < end; ++p) {
            for (int q = 0; q < 3; ++q) {  // G^T (v dS/dmu_y), G^T (v dS/dE[YY]), G^T (v dS/dE[XY])
                const float *src = dp + (p * 3 + q) * HWo;
                for (int64_t i = 0; i < HWo; ++i) g[i] = vp[p] * src[i];
                filter_w_t(g.data(), d.Ho, d.Wo, w, d.K, tmp.data());
                filter_h_t(tmp.data(), d.Ho, d.W, w, d.K, back.data() + q * HW);
            }
            const float *x = xp + p * HW, *y = yp + p * HW;
            float *o = out + p * HW;
            for (int64_t i = 0; i < HW; ++i) o[i] = back[i] + 2.0f * y[i] * back[HW + i] + x[i] * back[2 * HW + i];
        }
    });
    return v_Y;
}

}  // namespace stealth_ns
