// Projection (EWA splatting) and SH colour of 3D Gaussians on the CPU, forward and backward.
//
// The readable reference with the same contract is stealth_ns/raster/projection.py (pure torch,
// differentiated by autograd); the math is gsplat 1.4.0's (fully_fused_projection with a pinhole
// camera, spherical_harmonics):
//   covariance  R(q/|q|) diag(s)^2 R^T, rotated into the camera: Sc = W S W^T;
//   the Jacobian of the pinhole projection evaluated at the point clamped to 1.3x the field of view;
//   cov2d = J Sc J^T + eps2d I; conic = inverse of cov2d (upper triangle), its determinant clamped
//   at 1e-10; radius = ceil(3 sqrt(largest eigenvalue)), 0 outside [near, far] or off screen.
//   colour = max(sum_k Y_k(d) c_k + 0.5, 0) with d the normalised direction camera centre -> mean.
// As in gsplat, a Gaussian with radius 0 in a camera gets colour 0 and no gradient from it (the
// rasterizer never reads it).  Each Gaussian's backward sums its cameras in a fixed order, one
// Gaussian per lane: deterministic, whatever the thread count.
//
// Vectorised across Gaussians: the per-Gaussian math is written once on kLanes-lane vectors (GCC vector
// extensions), one Gaussian per lane, gathered from and scattered to the [N, 3|4] rows in blocks of
// kLanes.  Every lane evaluates the same float
// expressions in the same order as a scalar loop would (no FMA contraction, no fast-math; sqrt and
// division are correctly rounded), so the results do not depend on the lane a Gaussian lands in.
// Branches become selects: masked-out lanes compute and are discarded, never stored.

#include "project_cpu.h"
#include "simd_width.h"
#include "tensor_checks.h"

#include <ATen/Parallel.h>
#include <ATen/ops/empty.h>
#include <ATen/ops/empty_like.h>

#include <algorithm>
#include <cmath>

namespace stealth_ns {
namespace {

constexpr int64_t kGrain = 512;

constexpr int kLanes = STEALTH_NS_FLOAT_LANES;  // one register (simd_width.h)
typedef float vf __attribute__((vector_size(4 * kLanes)));
typedef int32_t vi __attribute__((vector_size(4 * kLanes)));  // masks: -1 (true) / 0 per lane

inline vf vmax(vf a, vf b) { return a < b ? b : a; }  // std::max(a, b), lane-wise
inline vf vmin(vf a, vf b) { return b < a ? b : a; }  // std::min(a, b), lane-wise
inline vf vsqrt(vf x) {
    vf r;
    for (int l = 0; l < kLanes; ++l) r[l] = std::sqrt(x[l]);  // one vsqrtps (-fno-math-errno)
    return r;
}
inline vf vceil(vf x) {
    vf r;
    for (int l = 0; l < kLanes; ++l) r[l] = std::ceil(x[l]);
    return r;
}
inline vf vset(float x) {
    vf r;
    for (int l = 0; l < kLanes; ++l) r[l] = x;  // exact broadcast (keeps the sign of -0)
    return r;
}
inline vf zeros() { return vf{}; }

// Lanes l < L of a block: floats [0, width) of row idx[l] of `src` (rows `stride` floats apart), as
// `width` vectors.  Lanes >= L repeat lane 0 (finite inputs, results never stored).
inline void gather(const float *src, int64_t stride, int width, const int64_t *idx, int L, vf *out) {
    const float *rows[kLanes];
    for (int l = 0; l < kLanes; ++l) rows[l] = src + stride * idx[l < L ? l : 0];
    for (int j = 0; j < width; ++j)
        for (int l = 0; l < kLanes; ++l) out[j][l] = rows[l][j];
}

// The inverse of gather for lanes l < L.
inline void scatter(const vf *in, int64_t stride, int width, const int64_t *idx, int L, float *dst) {
    for (int l = 0; l < L; ++l) {
        float *row = dst + stride * idx[l];
        for (int j = 0; j < width; ++j) row[j] = in[j][l];
    }
}

struct Camera {
    float R[3][3];
    float t[3];
    float fx, fy, cx, cy;
    float lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg;
    float centre[3];  // -R^T t
};

std::vector<Camera> cameras(const at::Tensor &viewmats, const at::Tensor &Ks, int64_t width, int64_t height) {
    check_cpu_f32(viewmats, "viewmats");
    TORCH_CHECK(viewmats.dim() == 3 && viewmats.size(1) == 4 && viewmats.size(2) == 4, "viewmats must be [C, 4, 4]");
    const int64_t C = viewmats.size(0);
    const float *v = viewmats.data_ptr<float>();
    const float *k = nullptr;
    if (Ks.defined() && Ks.numel() > 0) {
        check_cpu_f32(Ks, "Ks");
        TORCH_CHECK(Ks.dim() == 3 && Ks.size(0) == C && Ks.size(1) == 3 && Ks.size(2) == 3, "Ks must be [C, 3, 3]");
        k = Ks.data_ptr<float>();
    }
    std::vector<Camera> out(C);
    for (int64_t c = 0; c < C; ++c) {
        Camera &cam = out[c];
        const float *m = v + 16 * c;
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < 3; ++j) cam.R[i][j] = m[4 * i + j];
            cam.t[i] = m[4 * i + 3];
        }
        for (int j = 0; j < 3; ++j)
            cam.centre[j] = -(cam.R[0][j] * cam.t[0] + cam.R[1][j] * cam.t[1] + cam.R[2][j] * cam.t[2]);
        if (k) {
            const float *kk = k + 9 * c;
            cam.fx = kk[0], cam.fy = kk[4], cam.cx = kk[2], cam.cy = kk[5];
            const float tan_fovx = 0.5f * (float)width / cam.fx, tan_fovy = 0.5f * (float)height / cam.fy;
            cam.lim_x_pos = ((float)width - cam.cx) / cam.fx + 0.3f * tan_fovx;
            cam.lim_x_neg = cam.cx / cam.fx + 0.3f * tan_fovx;
            cam.lim_y_pos = ((float)height - cam.cy) / cam.fy + 0.3f * tan_fovy;
            cam.lim_y_neg = cam.cy / cam.fy + 0.3f * tan_fovy;
        }
    }
    return out;
}

// Rotation matrix of q / max(|q|, 1e-12) (torch's F.normalize); qn, inv_norm kept for the backward.
inline void quat_to_rot(const vf q[4], vf qn[4], vf &inv_norm, vf R[3][3]) {
    const vf norm = vsqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    inv_norm = 1.0f / vmax(norm, vset(1e-12f));
    for (int i = 0; i < 4; ++i) qn[i] = q[i] * inv_norm;
    const vf w = qn[0], x = qn[1], y = qn[2], z = qn[3];
    R[0][0] = 1.0f - 2.0f * (y * y + z * z), R[0][1] = 2.0f * (x * y - w * z), R[0][2] = 2.0f * (x * z + w * y);
    R[1][0] = 2.0f * (x * y + w * z), R[1][1] = 1.0f - 2.0f * (x * x + z * z), R[1][2] = 2.0f * (y * z - w * x);
    R[2][0] = 2.0f * (x * z - w * y), R[2][1] = 2.0f * (y * z + w * x), R[2][2] = 1.0f - 2.0f * (x * x + y * y);
}

// Everything the projection of one Gaussian into one camera computes (the backward recomputes it).
struct Projected {
    vf p[3];          // camera-space mean
    vf Sc[3][3];      // camera-space covariance
    vf J[2][3];       // projection Jacobian (at the clamped point)
    vf ux, uy;        // clamped tx/tz, ty/tz
    vi x_free, y_free;  // the clamp did not bind
    vf a, b, c, det;
    vi det_free;      // the determinant was not clamped
    vf mean2d[2];
    vi radius;
};

struct Clip {
    float eps2d, near_plane, far_plane, radius_clip;
};

inline void project_one(const Camera &cam, const vf mean[3], const vf S[3][3], int64_t width, int64_t height,
                        const Clip &clip, Projected &o) {
    for (int i = 0; i < 3; ++i)
        o.p[i] = cam.R[i][0] * mean[0] + cam.R[i][1] * mean[1] + cam.R[i][2] * mean[2] + cam.t[i];
    vf RS[3][3];  // R S
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) RS[i][j] = cam.R[i][0] * S[0][j] + cam.R[i][1] * S[1][j] + cam.R[i][2] * S[2][j];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            o.Sc[i][j] = RS[i][0] * cam.R[j][0] + RS[i][1] * cam.R[j][1] + RS[i][2] * cam.R[j][2];
    const vf tx = o.p[0], ty = o.p[1], tz = o.p[2];
    const vf rx = tx / tz, ry = ty / tz;
    o.ux = vmin(vmax(rx, vset(-cam.lim_x_neg)), vset(cam.lim_x_pos));
    o.uy = vmin(vmax(ry, vset(-cam.lim_y_neg)), vset(cam.lim_y_pos));
    o.x_free = (rx >= -cam.lim_x_neg) & (rx <= cam.lim_x_pos);
    o.y_free = (ry >= -cam.lim_y_neg) & (ry <= cam.lim_y_pos);
    const vf txc = tz * o.ux, tyc = tz * o.uy;
    o.J[0][0] = cam.fx / tz, o.J[0][1] = zeros(), o.J[0][2] = -cam.fx * txc / (tz * tz);
    o.J[1][0] = zeros(), o.J[1][1] = cam.fy / tz, o.J[1][2] = -cam.fy * tyc / (tz * tz);
    vf JS[2][3];
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 3; ++j)
            JS[i][j] = o.J[i][0] * o.Sc[0][j] + o.J[i][1] * o.Sc[1][j] + o.J[i][2] * o.Sc[2][j];
    vf cov[2][2];
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 2; ++j) cov[i][j] = JS[i][0] * o.J[j][0] + JS[i][1] * o.J[j][1] + JS[i][2] * o.J[j][2];
    o.mean2d[0] = cam.fx * tx / tz + cam.cx;
    o.mean2d[1] = cam.fy * ty / tz + cam.cy;
    o.a = cov[0][0] + clip.eps2d;
    o.b = 0.5f * (cov[0][1] + cov[1][0]);
    o.c = cov[1][1] + clip.eps2d;
    const vf det_raw = o.a * o.c - o.b * o.b;
    o.det_free = det_raw >= 1e-10f;
    o.det = o.det_free ? det_raw : vset(1e-10f);
    const vf half_trace = 0.5f * (o.a + o.c);
    const vf lam_max = half_trace + vsqrt(vmax(half_trace * half_trace - o.det, vset(0.01f)));
    const vf radius = vceil(3.0f * vsqrt(lam_max));
    const vi valid = (o.det > 0.0f) & (tz > clip.near_plane) & (tz < clip.far_plane) & (radius > clip.radius_clip);
    const vi inside = (o.mean2d[0] + radius > 0.0f) & (o.mean2d[0] - radius < (float)width) &
                      (o.mean2d[1] + radius > 0.0f) & (o.mean2d[1] - radius < (float)height);
    o.radius = (valid & inside) ? __builtin_convertvector(radius, vi) : vi{};
}

// Covariance S = M M^T with M = R(q) diag(s).
inline void covariance(const vf quat[4], const vf scale[3], vf qn[4], vf &inv_norm, vf Rq[3][3], vf M[3][3],
                       vf S[3][3]) {
    quat_to_rot(quat, qn, inv_norm, Rq);
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) M[i][j] = Rq[i][j] * scale[j];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) S[i][j] = M[i][0] * M[j][0] + M[i][1] * M[j][1] + M[i][2] * M[j][2];
}

// Gradient of one camera's outputs w.r.t. p (camera-space mean) and Sc (camera covariance).
inline void project_one_bwd(const Camera &cam, const Projected &o, const vf v_mean2d[2], vf v_depth,
                            const vf v_conic[3], vf v_p[3], vf v_Sc[3][3]) {
    const vf a = o.a, b = o.b, c = o.c, det = o.det;
    // conic = (c, -b, a) / det
    const vf v_det = o.det_free ? -(v_conic[0] * c - v_conic[1] * b + v_conic[2] * a) / (det * det) : zeros();
    const vf v_a = v_conic[2] / det + v_det * c;
    const vf v_b = -v_conic[1] / det - 2.0f * b * v_det;
    const vf v_c = v_conic[0] / det + v_det * a;
    const vf V[2][2] = {{v_a, 0.5f * v_b}, {0.5f * v_b, v_c}};  // gradient of cov2d (symmetric)
    // cov2d = J Sc J^T:  v_Sc = J^T V J,  v_J = 2 V J Sc
    vf VJ[2][3];
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 3; ++j) VJ[i][j] = V[i][0] * o.J[0][j] + V[i][1] * o.J[1][j];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) v_Sc[i][j] = o.J[0][i] * VJ[0][j] + o.J[1][i] * VJ[1][j];
    vf v_J[2][3];
    for (int i = 0; i < 2; ++i)
        for (int j = 0; j < 3; ++j)
            v_J[i][j] = 2.0f * (VJ[i][0] * o.Sc[0][j] + VJ[i][1] * o.Sc[1][j] + VJ[i][2] * o.Sc[2][j]);
    const vf tx = o.p[0], ty = o.p[1], tz = o.p[2];
    const vf tz2 = tz * tz, tz3 = tz2 * tz;
    // J00 = fx/tz, J11 = fy/tz, J02 = -fx txc/tz^2, J12 = -fy tyc/tz^2 with txc = tz * clamp(tx/tz)
    const vf txc = tz * o.ux, tyc = tz * o.uy;
    const vf dtxc_dtx = o.x_free ? vset(1.0f) : zeros(), dtyc_dty = o.y_free ? vset(1.0f) : zeros();
    const vf dtxc_dtz = o.ux - (o.x_free ? tx / tz : zeros());
    const vf dtyc_dtz = o.uy - (o.y_free ? ty / tz : zeros());
    vf gx = zeros(), gy = zeros(), gz = v_depth;
    gz += -cam.fx / tz2 * v_J[0][0] - cam.fy / tz2 * v_J[1][1];
    gx += -cam.fx / tz2 * dtxc_dtx * v_J[0][2];
    gz += (-cam.fx * dtxc_dtz / tz2 + 2.0f * cam.fx * txc / tz3) * v_J[0][2];
    gy += -cam.fy / tz2 * dtyc_dty * v_J[1][2];
    gz += (-cam.fy * dtyc_dtz / tz2 + 2.0f * cam.fy * tyc / tz3) * v_J[1][2];
    // mean2d = (fx tx/tz + cx, fy ty/tz + cy)
    gx += cam.fx / tz * v_mean2d[0];
    gy += cam.fy / tz * v_mean2d[1];
    gz += -cam.fx * tx / tz2 * v_mean2d[0] - cam.fy * ty / tz2 * v_mean2d[1];
    v_p[0] = gx, v_p[1] = gy, v_p[2] = gz;
}

// Gradient of R(q / |q|) (G = dL/dR) -> dL/dq.
inline void quat_bwd(const vf qn[4], vf inv_norm, const vf G[3][3], vf v_q[4]) {
    const vf w = qn[0], x = qn[1], y = qn[2], z = qn[3];
    vf v[4];
    v[0] = 2.0f * (-z * G[0][1] + y * G[0][2] + z * G[1][0] - x * G[1][2] - y * G[2][0] + x * G[2][1]);
    v[1] = 2.0f * (y * G[0][1] + z * G[0][2] + y * G[1][0] - 2.0f * x * G[1][1] - w * G[1][2] + z * G[2][0] +
                   w * G[2][1] - 2.0f * x * G[2][2]);
    v[2] = 2.0f * (-2.0f * y * G[0][0] + x * G[0][1] + w * G[0][2] + x * G[1][0] + z * G[1][2] - w * G[2][0] +
                   z * G[2][1] - 2.0f * y * G[2][2]);
    v[3] = 2.0f * (-2.0f * z * G[0][0] - w * G[0][1] + x * G[0][2] + w * G[1][0] - 2.0f * z * G[1][1] +
                   y * G[1][2] + x * G[2][0] + y * G[2][1]);
    const vf dot = qn[0] * v[0] + qn[1] * v[1] + qn[2] * v[2] + qn[3] * v[3];
    for (int i = 0; i < 4; ++i) v_q[i] = (v[i] - qn[i] * dot) * inv_norm;
}

// Real SH constants (degree 0..3), as gsplat and the 3DGS reference.
constexpr float C0 = 0.28209479177387814f;
constexpr float C1 = 0.4886025119029199f;
constexpr float C2[5] = {1.0925484305920792f, -1.0925484305920792f, 0.31539156525252005f, -1.0925484305920792f,
                         0.5462742152960396f};
constexpr float C3[7] = {-0.5900435899266435f, 2.890611442640554f, -0.4570457994644658f, 0.3731763325901154f,
                         -0.4570457994644658f, 1.445305721320277f, -0.5900435899266435f};

// Basis values Y_k(n) for k < (degree + 1)^2 and, when grad is not null, their gradients dY_k/dn.
inline void sh_basis(int degree, vf x, vf y, vf z, vf *Y, vf (*grad)[3]) {
    Y[0] = vset(C0);
    if (grad) grad[0][0] = grad[0][1] = grad[0][2] = zeros();
    if (degree < 1) return;
    Y[1] = -C1 * y, Y[2] = C1 * z, Y[3] = -C1 * x;
    if (grad) {
        grad[1][0] = zeros(), grad[1][1] = vset(-C1), grad[1][2] = zeros();
        grad[2][0] = zeros(), grad[2][1] = zeros(), grad[2][2] = vset(C1);
        grad[3][0] = vset(-C1), grad[3][1] = zeros(), grad[3][2] = zeros();
    }
    if (degree < 2) return;
    const vf xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
    Y[4] = C2[0] * xy, Y[5] = C2[1] * yz, Y[6] = C2[2] * (2.0f * zz - xx - yy), Y[7] = C2[3] * xz;
    Y[8] = C2[4] * (xx - yy);
    if (grad) {
        grad[4][0] = C2[0] * y, grad[4][1] = C2[0] * x, grad[4][2] = zeros();
        grad[5][0] = zeros(), grad[5][1] = C2[1] * z, grad[5][2] = C2[1] * y;
        grad[6][0] = -2.0f * C2[2] * x, grad[6][1] = -2.0f * C2[2] * y, grad[6][2] = 4.0f * C2[2] * z;
        grad[7][0] = C2[3] * z, grad[7][1] = zeros(), grad[7][2] = C2[3] * x;
        grad[8][0] = 2.0f * C2[4] * x, grad[8][1] = -2.0f * C2[4] * y, grad[8][2] = zeros();
    }
    if (degree < 3) return;
    Y[9] = C3[0] * y * (3.0f * xx - yy);
    Y[10] = C3[1] * xy * z;
    Y[11] = C3[2] * y * (4.0f * zz - xx - yy);
    Y[12] = C3[3] * z * (2.0f * zz - 3.0f * xx - 3.0f * yy);
    Y[13] = C3[4] * x * (4.0f * zz - xx - yy);
    Y[14] = C3[5] * z * (xx - yy);
    Y[15] = C3[6] * x * (xx - 3.0f * yy);
    if (grad) {
        grad[9][0] = C3[0] * 6.0f * xy, grad[9][1] = C3[0] * (3.0f * xx - 3.0f * yy), grad[9][2] = zeros();
        grad[10][0] = C3[1] * yz, grad[10][1] = C3[1] * xz, grad[10][2] = C3[1] * xy;
        grad[11][0] = C3[2] * -2.0f * xy, grad[11][1] = C3[2] * (4.0f * zz - xx - 3.0f * yy);
        grad[11][2] = C3[2] * 8.0f * yz;
        grad[12][0] = C3[3] * -6.0f * xz, grad[12][1] = C3[3] * -6.0f * yz;
        grad[12][2] = C3[3] * (6.0f * zz - 3.0f * xx - 3.0f * yy);
        grad[13][0] = C3[4] * (4.0f * zz - 3.0f * xx - yy), grad[13][1] = C3[4] * -2.0f * xy;
        grad[13][2] = C3[4] * 8.0f * xz;
        grad[14][0] = C3[5] * 2.0f * xz, grad[14][1] = C3[5] * -2.0f * yz, grad[14][2] = C3[5] * (xx - yy);
        grad[15][0] = C3[6] * (3.0f * xx - 3.0f * yy), grad[15][1] = C3[6] * -6.0f * xy, grad[15][2] = zeros();
    }
}

struct ShInputs {
    int64_t C, N, R;  // cameras, Gaussians, higher-order coefficients stored per Gaussian
    int degree, k_used;
};

ShInputs check_sh(const at::Tensor &means, const at::Tensor &viewmats, const at::Tensor &dc,
                  const at::Tensor &rest, int64_t degree, const at::Tensor &radii) {
    check_cpu_f32(means, "means");
    check_cpu_f32(dc, "sh_dc");
    check_cpu_f32(rest, "sh_rest");
    check_cpu_i32(radii, "radii");
    TORCH_CHECK(degree >= 0 && degree <= 3, "sh degree must be in 0..3");
    const int64_t N = means.size(0), C = viewmats.size(0);
    TORCH_CHECK(dc.dim() == 2 && dc.size(0) == N && dc.size(1) == 3, "sh_dc must be [N, 3]");
    TORCH_CHECK(rest.dim() == 3 && rest.size(0) == N && rest.size(2) == 3, "sh_rest must be [N, K - 1, 3]");
    const int k_used = (int)((degree + 1) * (degree + 1));
    TORCH_CHECK(rest.size(1) + 1 >= k_used, "sh degree ", degree, " needs ", k_used, " coefficients");
    TORCH_CHECK(radii.dim() == 2 && radii.size(0) == C && radii.size(1) == N, "radii must be [C, N]");
    return {C, N, rest.size(1), (int)degree, k_used};
}

// The n in [begin, end) with radius > 0 in camera `cam` of the [C, N] radii, or in any camera when cam < 0.
std::vector<int64_t> seen_in(const int32_t *radii, int64_t C, int64_t N, int64_t cam, int64_t begin, int64_t end) {
    std::vector<int64_t> seen;
    seen.reserve(end - begin);
    for (int64_t n = begin; n < end; ++n) {
        bool any = false;
        for (int64_t c = cam < 0 ? 0 : cam; c < (cam < 0 ? C : cam + 1); ++c) any = any || radii[c * N + n] > 0;
        if (any) seen.push_back(n);
    }
    return seen;
}

// Rows c * N + idx[l] of camera c's [C, N, ...] arrays for the lanes of a block (lanes >= L repeat lane 0,
// as gather does) and the mask of the lanes whose Gaussian the camera sees (radius > 0).
inline vi camera_rows(const int32_t *radii, int64_t c, int64_t N, const int64_t *idx, int L,
                      int64_t rows[kLanes]) {
    vi vis;
    for (int l = 0; l < kLanes; ++l) {
        rows[l] = c * N + idx[l < L ? l : 0];
        vis[l] = radii[rows[l]] > 0 ? -1 : 0;
    }
    return vis;
}

// The k_used coefficients of a block, coef[3 k + ch] (the DC term is stored apart from the rest).
inline void gather_coeffs(const ShInputs &in, const float *dc, const float *rest, const int64_t *idx, int L,
                          vf coef[48]) {
    gather(dc, 3, 3, idx, L, coef);
    gather(rest, 3 * in.R, 3 * (in.k_used - 1), idx, L, coef + 3);
}

// Unit direction u (and 1 / distance) from a camera centre to the means of a block.
inline void view_dirs(const Camera &cam, const vf mean[3], vf u[3], vf &inv) {
    vf d[3];
    for (int j = 0; j < 3; ++j) d[j] = mean[j] - cam.centre[j];
    inv = 1.0f / vmax(vsqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]), vset(1e-12f));
    for (int j = 0; j < 3; ++j) u[j] = d[j] * inv;
}

// sum_k Y_k c_k per channel (before the + 0.5 and the clamp).
inline void sh_sum(const ShInputs &in, const vf *Y, const vf coef[48], vf v[3]) {
    for (int ch = 0; ch < 3; ++ch) {
        v[ch] = zeros();
        for (int k = 0; k < in.k_used; ++k) v[ch] += Y[k] * coef[3 * k + ch];
    }
}

}  // namespace

std::vector<at::Tensor> project_fwd(const at::Tensor &means, const at::Tensor &quats,
                                    const at::Tensor &scales, const at::Tensor &viewmats,
                                    const at::Tensor &Ks, int64_t width, int64_t height, double eps2d,
                                    double near_plane, double far_plane, double radius_clip) {
    check_cpu_f32(means, "means");
    check_cpu_f32(quats, "quats");
    check_cpu_f32(scales, "scales");
    const int64_t N = means.size(0);
    TORCH_CHECK(means.dim() == 2 && means.size(1) == 3, "means must be [N, 3]");
    TORCH_CHECK(quats.dim() == 2 && quats.size(0) == N && quats.size(1) == 4, "quats must be [N, 4]");
    TORCH_CHECK(scales.dim() == 2 && scales.size(0) == N && scales.size(1) == 3, "scales must be [N, 3]");
    const std::vector<Camera> cams = cameras(viewmats, Ks, width, height);
    const int64_t C = (int64_t)cams.size();
    auto fopt = means.options();
    auto radii = at::empty({C, N}, fopt.dtype(at::kInt));
    auto means2d = at::empty({C, N, 2}, fopt);
    auto depths = at::empty({C, N}, fopt);
    auto conics = at::empty({C, N, 3}, fopt);
    const float *m = means.data_ptr<float>(), *q = quats.data_ptr<float>(), *s = scales.data_ptr<float>();
    int32_t *r_out = radii.data_ptr<int32_t>();
    float *m2_out = means2d.data_ptr<float>(), *d_out = depths.data_ptr<float>(), *c_out = conics.data_ptr<float>();
    const Clip clip{(float)eps2d, (float)near_plane, (float)far_plane, (float)radius_clip};
    at::parallel_for(0, N, kGrain, [&](int64_t begin, int64_t end) {
        int64_t idx[kLanes];
        for (int64_t n0 = begin; n0 < end; n0 += kLanes) {
            const int L = (int)std::min<int64_t>(kLanes, end - n0);
            for (int l = 0; l < kLanes; ++l) idx[l] = n0 + l;
            vf mean[3], quat[4], scale[3], qn[4], inv_norm, Rq[3][3], M[3][3], S[3][3];
            gather(m, 3, 3, idx, L, mean);
            gather(q, 4, 4, idx, L, quat);
            gather(s, 3, 3, idx, L, scale);
            covariance(quat, scale, qn, inv_norm, Rq, M, S);
            for (int64_t c = 0; c < C; ++c) {
                Projected o;
                project_one(cams[c], mean, S, width, height, clip, o);
                const vf conic[3] = {o.c / o.det, -o.b / o.det, o.a / o.det};
                const int64_t i0 = c * N + n0;
                for (int l = 0; l < L; ++l) r_out[i0 + l] = o.radius[l], d_out[i0 + l] = o.p[2][l];
                int64_t rows[kLanes];
                for (int l = 0; l < kLanes; ++l) rows[l] = i0 + l;
                scatter(o.mean2d, 2, 2, rows, L, m2_out);
                scatter(conic, 3, 3, rows, L, c_out);
            }
        }
    });
    return {radii, means2d, depths, conics};
}

std::vector<at::Tensor> project_bwd(const at::Tensor &means, const at::Tensor &quats,
                                    const at::Tensor &scales, const at::Tensor &viewmats,
                                    const at::Tensor &Ks, int64_t width, int64_t height, double eps2d,
                                    const at::Tensor &radii, const at::Tensor &v_means2d,
                                    const at::Tensor &v_depths, const at::Tensor &v_conics) {
    check_cpu_f32(v_means2d, "v_means2d");
    check_cpu_f32(v_depths, "v_depths");
    check_cpu_f32(v_conics, "v_conics");
    const std::vector<Camera> cams = cameras(viewmats, Ks, width, height);
    const int64_t C = (int64_t)cams.size(), N = means.size(0);
    TORCH_CHECK(radii.numel() == C * N && v_means2d.numel() == 2 * C * N && v_depths.numel() == C * N &&
                    v_conics.numel() == 3 * C * N,
                "gradients must be [C, N, ...]");
    auto v_means = at::empty({N, 3}, means.options());
    auto v_quats = at::empty({N, 4}, means.options());
    auto v_scales = at::empty({N, 3}, means.options());
    const float *m = means.data_ptr<float>(), *q = quats.data_ptr<float>(), *s = scales.data_ptr<float>();
    const int32_t *r = radii.data_ptr<int32_t>();
    const float *g2 = v_means2d.data_ptr<float>(), *gd = v_depths.data_ptr<float>(), *gc = v_conics.data_ptr<float>();
    float *vm = v_means.data_ptr<float>(), *vq = v_quats.data_ptr<float>(), *vs = v_scales.data_ptr<float>();
    const Clip clip{(float)eps2d, 0.0f, 0.0f, 0.0f};
    at::parallel_for(0, N, kGrain, [&](int64_t begin, int64_t end) {
        // each task zero-fills its own rows (in cache), then does the Gaussians some camera sees
        std::fill(vm + 3 * begin, vm + 3 * end, 0.0f);
        std::fill(vq + 4 * begin, vq + 4 * end, 0.0f);
        std::fill(vs + 3 * begin, vs + 3 * end, 0.0f);
        const std::vector<int64_t> seen = seen_in(r, C, N, -1, begin, end);
        for (size_t b0 = 0; b0 < seen.size(); b0 += kLanes) {
            const int64_t *idx = seen.data() + b0;
            const int L = (int)std::min<size_t>(kLanes, seen.size() - b0);
            vf mean[3], quat[4], scale[3], qn[4], inv_norm, Rq[3][3], M[3][3], S[3][3];
            gather(m, 3, 3, idx, L, mean);
            gather(q, 4, 4, idx, L, quat);
            gather(s, 3, 3, idx, L, scale);
            covariance(quat, scale, qn, inv_norm, Rq, M, S);
            vf v_mean[3] = {}, v_S[3][3] = {};
            for (int64_t c = 0; c < C; ++c) {
                const Camera &cam = cams[c];
                int64_t rows[kLanes];
                const vi vis = camera_rows(r, c, N, idx, L, rows);
                vf v_m2[2], v_con[3], v_d[1];
                gather(g2, 2, 2, rows, L, v_m2);
                gather(gc, 3, 3, rows, L, v_con);
                gather(gd, 1, 1, rows, L, v_d);
                Projected o;
                project_one(cam, mean, S, width, height, clip, o);
                vf v_p[3], v_Sc[3][3];
                project_one_bwd(cam, o, v_m2, v_d[0], v_con, v_p, v_Sc);
                // p = R mean + t; Sc = R S R^T (a camera that does not see the Gaussian adds nothing)
                for (int j = 0; j < 3; ++j)
                    v_mean[j] = vis ? v_mean[j] + (cam.R[0][j] * v_p[0] + cam.R[1][j] * v_p[1] + cam.R[2][j] * v_p[2])
                                    : v_mean[j];
                vf T[3][3];  // R^T v_Sc
                for (int i2 = 0; i2 < 3; ++i2)
                    for (int j = 0; j < 3; ++j)
                        T[i2][j] = cam.R[0][i2] * v_Sc[0][j] + cam.R[1][i2] * v_Sc[1][j] + cam.R[2][i2] * v_Sc[2][j];
                for (int i2 = 0; i2 < 3; ++i2)
                    for (int j = 0; j < 3; ++j)
                        v_S[i2][j] = vis ? v_S[i2][j] + (T[i2][0] * cam.R[0][j] + T[i2][1] * cam.R[1][j] +
                                                         T[i2][2] * cam.R[2][j])
                                         : v_S[i2][j];
            }
            // S = M M^T (v_S symmetric): v_M = (v_S + v_S^T) M; M = Rq diag(s)
            vf v_Rq[3][3], v_scale[3] = {}, v_quat[4];
            for (int i2 = 0; i2 < 3; ++i2)
                for (int j = 0; j < 3; ++j) {
                    vf v_M = zeros();
                    for (int k = 0; k < 3; ++k) v_M += (v_S[i2][k] + v_S[k][i2]) * M[k][j];
                    v_Rq[i2][j] = v_M * scale[j];
                    v_scale[j] += v_M * Rq[i2][j];
                }
            quat_bwd(qn, inv_norm, v_Rq, v_quat);
            scatter(v_mean, 3, 3, idx, L, vm);
            scatter(v_quat, 4, 4, idx, L, vq);
            scatter(v_scale, 3, 3, idx, L, vs);
        }
    });
    return {v_means, v_quats, v_scales};
}

at::Tensor sh_fwd(const at::Tensor &means, const at::Tensor &viewmats, const at::Tensor &dc,
                  const at::Tensor &rest, int64_t degree, const at::Tensor &radii) {
    const ShInputs in = check_sh(means, viewmats, dc, rest, degree, radii);
    const std::vector<Camera> cams = cameras(viewmats, at::Tensor(), 0, 0);
    auto colors = at::empty({in.C, in.N, 3}, means.options());
    const float *m = means.data_ptr<float>(), *cdc = dc.data_ptr<float>(), *crest = rest.data_ptr<float>();
    const int32_t *r = radii.data_ptr<int32_t>();
    float *out = colors.data_ptr<float>();
    at::parallel_for(0, in.N, kGrain, [&](int64_t begin, int64_t end) {
        for (int64_t c = 0; c < in.C; ++c) {
            std::fill(out + 3 * (c * in.N + begin), out + 3 * (c * in.N + end), 0.0f);
            const std::vector<int64_t> seen = seen_in(r, in.C, in.N, c, begin, end);
            for (size_t b0 = 0; b0 < seen.size(); b0 += kLanes) {
                const int64_t *idx = seen.data() + b0;
                const int L = (int)std::min<size_t>(kLanes, seen.size() - b0);
                vf mean[3], coef[48], u[3], inv, Y[16], v[3];
                gather(m, 3, 3, idx, L, mean);
                gather_coeffs(in, cdc, crest, idx, L, coef);
                view_dirs(cams[c], mean, u, inv);
                sh_basis(in.degree, u[0], u[1], u[2], Y, nullptr);
                sh_sum(in, Y, coef, v);
                for (int ch = 0; ch < 3; ++ch) v[ch] = vmax(v[ch] + 0.5f, zeros());
                scatter(v, 3, 3, idx, L, out + 3 * c * in.N);
            }
        }
    });
    return colors;
}

std::vector<at::Tensor> sh_bwd(const at::Tensor &means, const at::Tensor &viewmats,
                               const at::Tensor &dc, const at::Tensor &rest, int64_t degree,
                               const at::Tensor &radii, const at::Tensor &v_colors) {
    const ShInputs in = check_sh(means, viewmats, dc, rest, degree, radii);
    check_cpu_f32(v_colors, "v_colors");
    TORCH_CHECK(v_colors.numel() == in.C * in.N * 3, "v_colors must be [C, N, 3]");
    const std::vector<Camera> cams = cameras(viewmats, at::Tensor(), 0, 0);
    // each task zero-fills its own rows (in cache) and writes the Gaussians some camera sees
    auto v_dc = at::empty_like(dc);
    auto v_rest = at::empty_like(rest);
    auto v_means = at::empty({in.N, 3}, means.options());
    const float *m = means.data_ptr<float>(), *cdc = dc.data_ptr<float>(), *crest = rest.data_ptr<float>();
    const float *g = v_colors.data_ptr<float>();
    const int32_t *r = radii.data_ptr<int32_t>();
    float *vdc = v_dc.data_ptr<float>(), *vrest = v_rest.data_ptr<float>(), *vm = v_means.data_ptr<float>();
    at::parallel_for(0, in.N, kGrain, [&](int64_t begin, int64_t end) {
        std::fill(vdc + 3 * begin, vdc + 3 * end, 0.0f);
        std::fill(vrest + 3 * in.R * begin, vrest + 3 * in.R * end, 0.0f);
        std::fill(vm + 3 * begin, vm + 3 * end, 0.0f);
        const std::vector<int64_t> seen = seen_in(r, in.C, in.N, -1, begin, end);
        for (size_t b0 = 0; b0 < seen.size(); b0 += kLanes) {
            const int64_t *idx = seen.data() + b0;
            const int L = (int)std::min<size_t>(kLanes, seen.size() - b0);
            vf mean[3], coef[48], vc[48] = {}, vmn[3] = {};  // vc: gradient of the k_used coefficients read
            gather(m, 3, 3, idx, L, mean);
            gather_coeffs(in, cdc, crest, idx, L, coef);
            for (int64_t c = 0; c < in.C; ++c) {
                int64_t rows[kLanes];
                const vi vis = camera_rows(r, c, in.N, idx, L, rows);
                vf gv[3], u[3], inv, Y[16], dY[16][3], v[3];
                gather(g, 3, 3, rows, L, gv);
                view_dirs(cams[c], mean, u, inv);
                sh_basis(in.degree, u[0], u[1], u[2], Y, dY);
                sh_sum(in, Y, coef, v);
                for (int ch = 0; ch < 3; ++ch) gv[ch] = (v[ch] + 0.5f >= 0.0f) ? gv[ch] : zeros();  // clamp at 0
                vf v_u[3] = {};
                for (int k = 0; k < in.k_used; ++k) {
                    vf dot = zeros();
                    for (int ch = 0; ch < 3; ++ch) {
                        vc[3 * k + ch] = vis ? vc[3 * k + ch] + Y[k] * gv[ch] : vc[3 * k + ch];
                        dot += coef[3 * k + ch] * gv[ch];
                    }
                    for (int j = 0; j < 3; ++j) v_u[j] += dot * dY[k][j];
                }
                const vf along = u[0] * v_u[0] + u[1] * v_u[1] + u[2] * v_u[2];
                for (int j = 0; j < 3; ++j) vmn[j] = vis ? vmn[j] + (v_u[j] - u[j] * along) * inv : vmn[j];
            }
            scatter(vc, 3, 3, idx, L, vdc);
            scatter(vc + 3, 3 * in.R, 3 * (in.k_used - 1), idx, L, vrest);
            scatter(vmn, 3, 3, idx, L, vm);
        }
    });
    return {v_dc, v_rest, v_means};
}

}  // namespace stealth_ns
