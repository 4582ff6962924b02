// The attack's per-pixel view noise (paper section 3.4) drawn on all cores, one pass over the image.
//
// torch.randn draws with one Mersenne Twister and cannot split its stream across threads, and the add,
// round, clamp and cast after it are more passes over the image (timings: docs/cpu_rasterizer.md).
// Here deviate pair j of stream `key` is a pure function of (key, j):
//
//   h        = splitmix64(key + (j + 1) * 0x9E3779B97F4A7C15)      (the SplitMix64 sequence)
//   u1       = ((h >> 40) + 1) / 2^24                 in (0, 1]
//   n2       = (h >> 8) mod 2^24                      the angle, in 2^-24 turns
//   r        = sqrt(max(-2 ln u1, 0))
//   z[2j]    = r cos(2 pi n2 / 2^24),   z[2j + 1] = r sin(2 pi n2 / 2^24)
//
// so any split over threads gives the same values.  Box-Muller with 24-bit uniforms, as torch's own
// CPU normal_, so |z| <= sqrt(48 ln 2) = 5.77.  ln, sin and cos are Cephes' single-precision
// polynomials (ln: exponent split off, mantissa in (sqrt(1/2), sqrt(2)]; the angle: the nearest
// quarter turn split off exactly in integers, the rest in [-pi/4, pi/4]), written as plain float
// operations so that the numpy reference in stealth_ns/attack/normal_draw.py rounds every one of them
// the same way: tests compare bitwise.  Compiled with -ffp-contract=off (no fused multiply-add); the
// constants are double literals rounded to float, as numpy's float32(...) rounds them.

#include "noise_cpu.h"

#include <ATen/Parallel.h>
#include <ATen/ops/empty.h>
#include <ATen/ops/empty_like.h>

#include <algorithm>
#include <cmath>
#include <cstring>

namespace stealth_ns {
namespace {

constexpr int64_t kPairs = 256;  // pairs per inner batch (a buffer of 512 floats on the stack)
constexpr int64_t kGrain = 64;   // batches per parallel task

inline uint64_t splitmix(uint64_t key, uint64_t j) {
    uint64_t z = key + (j + 1) * 0x9E3779B97F4A7C15ull;
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

inline float ln_u1(int32_t u) {  // ln(u / 2^24), u = (h >> 40) + 1
    const float f = (float)u;  // 1 .. 2^24, exact
    uint32_t bits;
    std::memcpy(&bits, &f, 4);
    const uint32_t mbits = (bits & 0x7FFFFFu) | 0x3F800000u;
    float m;
    std::memcpy(&m, &mbits, 4);  // [1, 2)
    // m > sqrt(2) as a comparison of the bit patterns (the same for positive floats) and the halving as
    // a product with 0.5 or 1 (exact): a float comparison's select keeps the AVX2 build's loop scalar
    const float sqrt2 = (float)1.41421356237309504880;
    uint32_t sqrt2_bits;
    std::memcpy(&sqrt2_bits, &sqrt2, 4);
    const int32_t big = mbits > sqrt2_bits ? 1 : 0;
    m = m * (big ? 0.5f : 1.f);
    const float e = (float)((int32_t)(bits >> 23) - 127 + big - 24);
    const float x = m - 1.f, z = x * x;
    float p = (float)7.0376836292E-2;
    p = p * x + (float)-1.1514610310E-1;
    p = p * x + (float)1.1676998740E-1;
    p = p * x + (float)-1.2420140846E-1;
    p = p * x + (float)1.4249322787E-1;
    p = p * x + (float)-1.6668057665E-1;
    p = p * x + (float)2.0000714765E-1;
    p = p * x + (float)-2.4999993993E-1;
    p = p * x + (float)3.3333331174E-1;
    float y = p * x * z;
    y = y + e * (float)-2.12194440E-4;
    y = y + (float)-0.5 * z;
    return (x + y) + e * (float)0.693359375;
}

// The two 24-bit uniforms of pair j: u = (h >> 40) + 1 (1 .. 2^24) and the angle n2 = (h >> 8) mod 2^24.
inline void uniforms(uint64_t key, uint64_t j, int32_t &u, int32_t &n2) {
    const uint64_t h = splitmix(key, j);
    u = (int32_t)((h >> 40) + 1);
    n2 = (int32_t)((h >> 8) & 0xFFFFFFu);
}

inline void normal_pair(int32_t u, int32_t n2, float &z0, float &z1) {
    const float r = std::sqrt(std::max(-2.f * ln_u1(u), 0.f));
    const int32_t q = (n2 + (1 << 21)) >> 22;                            // nearest quarter turn, 0 .. 4
    const float a = (float)(n2 - (q << 22)) * (float)5.9604644775390625E-8 * (float)6.28318530717958647692;
    const float z = a * a;
    float s = (float)-1.9515295891E-4;
    s = s * z + (float)8.3321608736E-3;
    s = s * z + (float)-1.6666654611E-1;
    s = s * z * a + a;
    float c = (float)2.443315711809948E-5;
    c = c * z + (float)-1.388731625493765E-3;
    c = c * z + (float)4.166664568298827E-2;
    c = c * z * z - (float)0.5 * z + 1.f;
    // quarter turn k: (cos, sin) = (c, s), (-s, c), (-c, -s), (s, -c) for k = 0, 1, 2, 3, as one swap and
    // two sign flips (single selects: the AVX2 build does not vectorise a chain of them)
    const int k = q & 3;
    const bool odd = (k & 1) != 0;
    const float a0 = odd ? s : c, a1 = odd ? c : s;
    const float cos_t = (k + 1) & 2 ? -a0 : a0;  // k = 1 or 2
    const float sin_t = k >= 2 ? -a1 : a1;
    z0 = r * cos_t;
    z1 = r * sin_t;
}

// Deviates 2 j0 .. 2 j1 - 1 into buf (j1 - j0 <= kPairs): branch-free loops the compiler vectorises.
// With AVX-512DQ one loop (64-bit lane multiplies for the hash).  Without them the hash's vectors hold
// 4 lanes, and in one loop so would the float part: the hash gets a loop of its own, the float part
// runs 8 lanes wide (timings: docs/cpu_rasterizer.md).
inline void fill_pairs(uint64_t key, int64_t j0, int64_t j1, float *buf) {
#if defined(__AVX512DQ__)
    for (int64_t j = j0; j < j1; ++j) {
        int32_t u, n2;
        uniforms(key, (uint64_t)j, u, n2);
        normal_pair(u, n2, buf[2 * (j - j0)], buf[2 * (j - j0) + 1]);
    }
#else
    int32_t u[kPairs], n2[kPairs];
    for (int64_t j = j0; j < j1; ++j) uniforms(key, (uint64_t)j, u[j - j0], n2[j - j0]);
    for (int64_t k = 0; k < j1 - j0; ++k) normal_pair(u[k], n2[k], buf[2 * k], buf[2 * k + 1]);
#endif
}

// body(i0, i1, z): deviates i0 .. i1 - 1 of the stream in z[0 .. i1 - i0), in parallel batches
template <class Body> void for_deviates(int64_t count, uint64_t key, Body &&body) {
    const int64_t n_batches = (count + 2 * kPairs - 1) / (2 * kPairs);
    at::parallel_for(0, n_batches, kGrain, [&](int64_t b0, int64_t b1) {
        float buf[2 * kPairs];
        for (int64_t b = b0; b < b1; ++b) {
            const int64_t i0 = b * 2 * kPairs, i1 = std::min(i0 + 2 * kPairs, count);
            fill_pairs(key, i0 / 2, (i1 + 1) / 2, buf);
            body(i0, i1, buf);
        }
    });
}

}  // namespace

at::Tensor normal_draw(int64_t count, int64_t key) {
    TORCH_CHECK(count >= 0, "count must be >= 0");
    at::Tensor out = at::empty({count}, at::TensorOptions().dtype(at::kFloat));
    float *o = out.data_ptr<float>();
    for_deviates(count, (uint64_t)key, [&](int64_t i0, int64_t i1, const float *z) {
        std::copy(z, z + (i1 - i0), o + i0);
    });
    return out;
}

at::Tensor noisy_u8(const at::Tensor &image, double sigma, int64_t key) {
    TORCH_CHECK(image.device().is_cpu(), "image must be a CPU tensor");
    TORCH_CHECK(image.scalar_type() == at::kByte, "image must be uint8");
    TORCH_CHECK(image.is_contiguous(), "image must be contiguous");
    at::Tensor out = at::empty_like(image);
    const uint8_t *in_all = image.data_ptr<uint8_t>();
    uint8_t *out_all = out.data_ptr<uint8_t>();
    const float s = (float)sigma;
    for_deviates(image.numel(), (uint64_t)key, [=](int64_t i0, int64_t i1, const float *__restrict__ z) {
        // local restrict pointers: a uint8 store may alias anything, which would keep this loop scalar
        const uint8_t *__restrict__ in = in_all + i0;
        uint8_t *__restrict__ o = out_all + i0;
        for (int64_t i = 0; i < i1 - i0; ++i) {
            const float v = std::rint((float)in[i] + s * z[i]);  // half to even (default mode), as torch.round
            o[i] = (uint8_t)(int32_t)std::min(std::max(v, 0.f), 255.f);
        }
    });
    return out;
}

}  // namespace stealth_ns
