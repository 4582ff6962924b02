// CPU rasterize-to-pixels for 3D Gaussian Splatting.
//
// Exact CPU counterpart of gsplat 1.4.0's CUDA kernels
//   gsplat/cuda/csrc/rasterize_to_pixels_fwd.cu  (forward)
//   gsplat/cuda/csrc/rasterize_to_pixels_bwd.cu  (backward)
//   gsplat/cuda/csrc/isect_tiles.cu              (tile intersection + sort + offsets)
// for the non-packed layout ([C, N, ...]), float32, any channel count D.
//
// Semantics (identical to gsplat): pixel centre (x + 0.5, y + 0.5);
//   sigma = 0.5 * (a dx^2 + c dy^2) + b dx dy, with (dx, dy) = mean2d - pixel;
//   alpha = min(0.999, opacity * exp(-sigma)); the Gaussian is skipped for the
//   pixel when sigma < 0 or alpha < 1/255; compositing front to back, stopping
//   (exclusively) when T * (1 - alpha) <= 1e-4; colour += T_final * background;
//   render_alpha = 1 - T_final.  The backward walks back to front from the saved
//   final transmittance and the index of the last contributor, recovering T by
//   division as gsplat does, and -- as gsplat -- does not propagate gradient
//   through the 0.999 clamp (condition `opacity * exp(-sigma) <= 0.999`).
//
// CPU design: one task per (camera, tile), handed out one at a time, longest list first
// (TaskQueue; a thread loads the next task's pixels into the cache while it runs one).
// Inside a task the loop order is Gaussian-outer / pixel-inner: the tile's list
// is walked in order (front to back in the forward, stopping when every pixel
// of the tile is done; back to front in the backward, starting at the largest
// last-contributor index of the tile).  Each Gaussian only visits the pixels of
// the tile that can pass the alpha >= 1/255 test: the ellipse
// {sigma <= log(255 * opacity)}, slightly enlarged to absorb float rounding,
// row by row, in blocks of 8 pixels, evaluated two blocks at a time (16-lane
// vectors; four in the backward with AVX-512, one where a register holds 4 floats;
// the sums over pixels still run block by block).  Every visited pixel runs
// exactly the per-pixel code of the CUDA kernel, so this culling changes the
// amount of work, never the result (`cull=false` scans whole tiles; the tests
// check both agree bitwise).  Per-pixel state (T, colour planes, last index,
// done mask; in the backward T, upstream gradients, accumulated colour)
// lives in per-thread tile scratch (structure of arrays).  Per-Gaussian data
// (conic, opacity, footprint) is precomputed in a parallel pass, for the Gaussians some tile list holds.
// Memory: O(image + C*N + n_isects) (+ per-thread tile scratch), never
// pairs x pixels.
//
// exp(): a vectorised Cephes-style expf (~1 ulp), identical in forward and
// backward; gsplat uses the approximate __expf.  Built without -ffast-math and
// with -ffp-contract=off, so results do not depend on FMA contraction and are
// bitwise reproducible across runs and thread counts (backward mode 0).
//
// Backward accumulation of per-Gaussian gradients coming from different tiles
// (mode argument of rasterize_bwd):
//   0: per-intersection buffer [n_isects, 6 + D] (each entry written by exactly
//      one tile, no race), reduced afterwards in isect order -> deterministic;
//   1: OpenMP atomics straight into the gradient tensors;
//   2: per-thread [C*N, 6 + D] buffers reduced at the end.
//
// rasterize_weights: the forward, also summing each Gaussian's T * alpha over the pixels of each tile
// (the colour gradient of the backward with an upstream gradient of ones, without the backward), into
// one slot per intersection, added in intersection order afterwards (as backward mode 0).

#include "rasterize_cpu.h"
#include "simd_width.h"
#include "tensor_checks.h"

#include <ATen/Parallel.h>
#include <ATen/ops/empty.h>
#include <ATen/ops/zeros.h>
#include <omp.h>
#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>  // only x86 builds use intrinsics (behind __AVX__ / __AVX512*__)
#endif

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <numeric>
#include <type_traits>
#include <utility>
#include <vector>

namespace stealth_ns {
namespace {

constexpr float kAlphaMin = 1.f / 255.f;
constexpr float kAlphaMax = 0.999f;
constexpr float kTransmittanceMin = 1e-4f;

// ---------------------------------------------------------------------------
// 8-wide float vectors (GCC vector extensions: AVX/AVX-512 registers when the
// target has them, emulated otherwise).  A tile row is processed in blocks of
// 8 pixels; every lane does exactly the scalar per-pixel computation.
// ---------------------------------------------------------------------------
constexpr int VW = 8;
typedef float vf __attribute__((vector_size(32)));
typedef int32_t vi __attribute__((vector_size(32)));
typedef float vf_u __attribute__((vector_size(32), aligned(4), __may_alias__));
typedef int32_t vi_u __attribute__((vector_size(32), aligned(4), __may_alias__));
typedef int64_t vl __attribute__((vector_size(32)));

inline vf vld(const float *p) { return *reinterpret_cast<const vf_u *>(p); }
inline void vst(float *p, vf v) { *reinterpret_cast<vf_u *>(p) = v; }
inline vi vild(const int32_t *p) { return *reinterpret_cast<const vi_u *>(p); }
inline void vist(int32_t *p, vi v) { *reinterpret_cast<vi_u *>(p) = v; }
// a in every lane of an 8- or 16-lane vector (written out: GCC builds the lane loop of a generic
// version one insert at a time, ~10 instructions on the way to every block's sigma)
template <class F> inline F bcast(float a);
template <> inline vf bcast<vf>(float a) { return vf{a, a, a, a, a, a, a, a}; }
inline vf vset(float a) { return bcast<vf>(a); }
inline vi viset(int32_t a) { return vi{a, a, a, a, a, a, a, a}; }
// "any lane set": one vptest with AVX (GCC compiles the four-word test below to lane extractions and
// ORs in general registers; docs/cpu_rasterizer.md)
inline bool vany(vi m) {
#if defined(__AVX__)
    return !_mm256_testz_si256((__m256i)m, (__m256i)m);
#else
    const vl t = (vl)m;
    return (t[0] | t[1] | t[2] | t[3]) != 0;
#endif
}
inline float vsum(vf v) {
    // fixed order -> deterministic
    return ((v[0] + v[1]) + (v[2] + v[3])) + ((v[4] + v[5]) + (v[6] + v[7]));
}
// out[i] = vsum(v[i]) for i < n, bitwise: eight at a time with horizontal adds, which add the lanes in
// vsum's order.  hadd(x, y) = [x0+x1, x2+x3, y0+y1, y2+y3, x4+x5, x6+x7, y4+y5, y6+y7]; two rounds
// of it give each vector's ((v0+v1)+(v2+v3)) in the low half and ((v4+v5)+(v6+v7)) in the high half.
inline void vsums(const vf *v, int n, float *out) {
    int i = 0;
#if defined(__AVX__)
    for (; i + 8 <= n; i += 8) {
        const __m256 a = _mm256_hadd_ps(
            _mm256_hadd_ps((__m256)v[i], (__m256)v[i + 1]), _mm256_hadd_ps((__m256)v[i + 2], (__m256)v[i + 3])
        );
        const __m256 b = _mm256_hadd_ps(
            _mm256_hadd_ps((__m256)v[i + 4], (__m256)v[i + 5]), _mm256_hadd_ps((__m256)v[i + 6], (__m256)v[i + 7])
        );
        _mm256_storeu_ps(out + i, _mm256_add_ps(_mm256_permute2f128_ps(a, b, 0x20), _mm256_permute2f128_ps(a, b, 0x31)));
    }
#endif
    for (; i < n; ++i) out[i] = vsum(v[i]);
}

// Lane-wise comparisons (-1 / 0 lanes) and selects of the 8-lane vectors.  Where a register holds 4
// floats (NEON, SSE; simd_width.h), GCC compiles the comparisons and selects of an 8-lane vector lane by
// lane, a scalar compare and select per lane (it splits only the arithmetic in halves): there they are
// applied to the two 4-lane halves (docs/cpu_rasterizer.md).  Elsewhere they are the vector operators
// themselves, as macros: as inline functions the same operators give other (equally correct) AVX2 and
// AVX-512 machine code.  The lanes' values are the same either way.
#if STEALTH_NS_FLOAT_LANES >= 8
#define V_LT(a, b) ((a) < (b))
#define V_LE(a, b) ((a) <= (b))
#define V_GT(a, b) ((a) > (b))
#define V_GE(a, b) ((a) >= (b))
#define V_NE0(a) ((a) != 0)
#define V_SEL(m, a, b) ((m) ? (a) : (b))
#else
typedef float vf4 __attribute__((vector_size(16)));
typedef int32_t vi4 __attribute__((vector_size(16)));
inline vf4 vlo4(vf v) { return __builtin_shufflevector(v, v, 0, 1, 2, 3); }
inline vf4 vhi4(vf v) { return __builtin_shufflevector(v, v, 4, 5, 6, 7); }
inline vi4 vlo4(vi v) { return __builtin_shufflevector(v, v, 0, 1, 2, 3); }
inline vi4 vhi4(vi v) { return __builtin_shufflevector(v, v, 4, 5, 6, 7); }
inline vf vcat4(vf4 a, vf4 b) { return __builtin_shufflevector(a, b, 0, 1, 2, 3, 4, 5, 6, 7); }
inline vi vcat4(vi4 a, vi4 b) { return __builtin_shufflevector(a, b, 0, 1, 2, 3, 4, 5, 6, 7); }
#define STEALTH_NS_HALVES_TEST(name, op)                                                                \
    template <class V> inline vi name(V a, V b) { return vcat4(vlo4(a) op vlo4(b), vhi4(a) op vhi4(b)); }
STEALTH_NS_HALVES_TEST(halves_lt, <)
STEALTH_NS_HALVES_TEST(halves_le, <=)
STEALTH_NS_HALVES_TEST(halves_gt, >)
STEALTH_NS_HALVES_TEST(halves_ge, >=)
#undef STEALTH_NS_HALVES_TEST
inline vi halves_ne0(vi a) { return vcat4(vlo4(a) != 0, vhi4(a) != 0); }
template <class V> inline V halves_sel(vi m, V a, V b) { return vcat4(vlo4(m) ? vlo4(a) : vlo4(b), vhi4(m) ? vhi4(a) : vhi4(b)); }
#define V_LT(a, b) halves_lt(a, b)
#define V_LE(a, b) halves_le(a, b)
#define V_GT(a, b) halves_gt(a, b)
#define V_GE(a, b) halves_ge(a, b)
#define V_NE0(a) halves_ne0(a)
#define V_SEL(m, a, b) halves_sel(m, a, b)
#endif
inline vf vsel(vi m, vf a, vf b) { return V_SEL(m, a, b); }
template <class F> inline F vmin(F a, F b) { return V_SEL(V_LT(a, b), a, b); }  // std::min(b, a) semantics
inline vf vsqrt(vf x) {
    vf r;
    for (int l = 0; l < VW; ++l) r[l] = std::sqrt(x[l]);  // one vsqrtps (-fno-math-errno)
    return r;
}
#if defined(__AVX__)
// one vroundps (GCC does not vectorise the lane loop below)
inline vf vceil(vf x) { return (vf)_mm256_round_ps((__m256)x, _MM_FROUND_TO_POS_INF | _MM_FROUND_NO_EXC); }
inline vf vfloor(vf x) { return (vf)_mm256_round_ps((__m256)x, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC); }
#else
inline vf vceil(vf x) {
    vf r;
    for (int l = 0; l < VW; ++l) r[l] = std::ceil(x[l]);
    return r;
}
inline vf vfloor(vf x) {
    vf r;
    for (int l = 0; l < VW; ++l) r[l] = std::floor(x[l]);
    return r;
}
#endif

// Two vectors used as one: each operation is applied to both halves, lane by lane.
template <class V> struct Pair {
    V a, b;
};
template <class S> constexpr bool kScalar = std::is_arithmetic_v<S>;
#define STEALTH_NS_PAIR_OP(op)                                                                         \
    template <class V> inline Pair<V> operator op(Pair<V> x, Pair<V> y) { return {x.a op y.a, x.b op y.b}; } \
    template <class V, class S, std::enable_if_t<kScalar<S>, int> = 0>                                  \
    inline Pair<V> operator op(Pair<V> x, S s) {                                                        \
        return {x.a op s, x.b op s};                                                                    \
    }                                                                                                   \
    template <class V, class S, std::enable_if_t<kScalar<S>, int> = 0>                                  \
    inline Pair<V> operator op(S s, Pair<V> y) {                                                        \
        return {s op y.a, s op y.b};                                                                    \
    }
STEALTH_NS_PAIR_OP(+)
STEALTH_NS_PAIR_OP(-)
STEALTH_NS_PAIR_OP(*)
STEALTH_NS_PAIR_OP(/)
STEALTH_NS_PAIR_OP(|)
STEALTH_NS_PAIR_OP(&)
#undef STEALTH_NS_PAIR_OP
template <class V> inline Pair<V> operator-(Pair<V> x) { return {-x.a, -x.b}; }
template <class V> inline Pair<V> operator~(Pair<V> x) { return {~x.a, ~x.b}; }
template <class V> inline Pair<V> &operator+=(Pair<V> &x, Pair<V> y) { return x = x + y; }
template <class V> inline Pair<V> vmin(Pair<V> x, Pair<V> y) { return {vmin(x.a, y.a), vmin(x.b, y.b)}; }

// 16-lane vectors: two blocks of 8 pixels side by side, lanes 0-7 the first block and 8-15 the
// second.  A Gaussian's blocks are evaluated two at a time: the work of a block is one long chain
// of dependent operations (the exp polynomial, the division of the backward), and one block at a
// time the processor does not overlap enough of them (docs/cpu_rasterizer.md).  Every lane does the
// operations of an 8-wide block, so the results are bitwise the same.  One register where it holds
// 16 floats (AVX-512).  Elsewhere a Pair of 8-lane vectors (simd_width.h: GCC compiles a 64-byte
// vector's comparisons and selects lane by lane there).
#if STEALTH_NS_FLOAT_LANES >= 16
#define STEALTH_NS_NATIVE16 1
typedef float vf16 __attribute__((vector_size(64)));
typedef int32_t vi16 __attribute__((vector_size(64)));
template <> inline vf16 bcast<vf16>(float a) { return vf16{a, a, a, a, a, a, a, a, a, a, a, a, a, a, a, a}; }
inline vf16 vcat(vf a, vf b) { return __builtin_shufflevector(a, b, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15); }
inline vi16 vcat(vi a, vi b) { return __builtin_shufflevector(a, b, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15); }
inline vf vlo(vf16 v) { return __builtin_shufflevector(v, v, 0, 1, 2, 3, 4, 5, 6, 7); }
inline vf vhi(vf16 v) { return __builtin_shufflevector(v, v, 8, 9, 10, 11, 12, 13, 14, 15); }
inline vi vlo(vi16 v) { return __builtin_shufflevector(v, v, 0, 1, 2, 3, 4, 5, 6, 7); }
inline vi vhi(vi16 v) { return __builtin_shufflevector(v, v, 8, 9, 10, 11, 12, 13, 14, 15); }
inline vf16 vcvt(vi16 v) { return __builtin_convertvector(v, vf16); }
#else
using vf16 = Pair<vf>;
using vi16 = Pair<vi>;
template <> inline vf16 bcast<vf16>(float a) { return {bcast<vf>(a), bcast<vf>(a)}; }
inline vf16 vcat(vf a, vf b) { return {a, b}; }
inline vi16 vcat(vi a, vi b) { return {a, b}; }
inline vf vlo(vf16 v) { return v.a; }
inline vf vhi(vf16 v) { return v.b; }
inline vi vlo(vi16 v) { return v.a; }
inline vi vhi(vi16 v) { return v.b; }
inline vf16 vcvt(vi16 v) { return {__builtin_convertvector(v.a, vf), __builtin_convertvector(v.b, vf)}; }
#endif
inline vf vcvt(vi v) { return __builtin_convertvector(v, vf); }

// Lane masks of the per-pixel tests, 8 lanes (lmask) or 16 (lmask16).  With AVX-512VL they live in
// mask registers (__mmask8, __mmask16), and the tests, selects and "any lane" checks are single
// instructions; GCC's vector booleans go through general registers lane by lane.  Elsewhere
// they are vector booleans (-1 / 0 lanes).  Comparisons are ordered and quiet, as the vector operators:
// false when a lane is NaN.
#if defined(__AVX512VL__) && defined(__AVX512DQ__)
typedef __mmask8 lmask;
typedef __mmask16 lmask16;
inline lmask m_le(vf a, vf b) { return _mm256_cmp_ps_mask((__m256)a, (__m256)b, _CMP_LE_OQ); }
inline lmask m_ge(vf a, vf b) { return _mm256_cmp_ps_mask((__m256)a, (__m256)b, _CMP_GE_OQ); }
inline lmask m_ilt(vi a, vi b) { return _mm256_cmplt_epi32_mask((__m256i)a, (__m256i)b); }
inline lmask m_ile(vi a, vi b) { return _mm256_cmple_epi32_mask((__m256i)a, (__m256i)b); }
inline lmask m_ige(vi a, vi b) { return _mm256_cmpge_epi32_mask((__m256i)a, (__m256i)b); }
inline lmask m_nonzero(vi a) { return _mm256_test_epi32_mask((__m256i)a, (__m256i)a); }
inline vi m_lanes(lmask m) { return (vi)_mm256_movm_epi32(m); }  // -1 / 0 per lane
inline bool m_any(lmask m) { return m != 0; }
inline int m_count(lmask m) { return __builtin_popcount(m); }
inline uint32_t m_bits(lmask m) { return m; }  // bit l: lane l
inline vf m_sel(lmask m, vf a, vf b) { return (vf)_mm256_mask_blend_ps(m, (__m256)b, (__m256)a); }
inline vi m_seli(lmask m, vi a, vi b) { return (vi)_mm256_mask_blend_epi32(m, (__m256i)b, (__m256i)a); }
inline lmask16 m_le(vf16 a, vf16 b) { return _mm512_cmp_ps_mask((__m512)a, (__m512)b, _CMP_LE_OQ); }
inline lmask16 m_ge(vf16 a, vf16 b) { return _mm512_cmp_ps_mask((__m512)a, (__m512)b, _CMP_GE_OQ); }
inline lmask16 m_ilt(vi16 a, vi16 b) { return _mm512_cmplt_epi32_mask((__m512i)a, (__m512i)b); }
inline lmask16 m_ile(vi16 a, vi16 b) { return _mm512_cmple_epi32_mask((__m512i)a, (__m512i)b); }
inline lmask16 m_ige(vi16 a, vi16 b) { return _mm512_cmpge_epi32_mask((__m512i)a, (__m512i)b); }
inline lmask16 m_nonzero(vi16 a) { return _mm512_test_epi32_mask((__m512i)a, (__m512i)a); }
inline vi16 m_lanes16(lmask16 m) { return (vi16)_mm512_movm_epi32(m); }
inline bool m_any16(lmask16 m) { return m != 0; }
inline int m_count16(lmask16 m) { return __builtin_popcount(m); }
inline lmask m_lo8(lmask16 m) { return (lmask)m; }  // lanes 0-7
inline lmask m_hi8(lmask16 m) { return (lmask)(m >> 8); }  // lanes 8-15
inline vf16 m_sel(lmask16 m, vf16 a, vf16 b) { return (vf16)_mm512_mask_blend_ps(m, (__m512)b, (__m512)a); }
inline vi16 m_seli(lmask16 m, vi16 a, vi16 b) { return (vi16)_mm512_mask_blend_epi32(m, (__m512i)b, (__m512i)a); }
// p[l] = v[l] where lane l of m is set; the other lanes of p keep their values
inline void m_stori(int32_t *p, lmask m, vi v) { _mm256_mask_storeu_epi32(p, m, (__m256i)v); }
#else
typedef vi lmask;
typedef vi16 lmask16;
// one definition for both widths
template <class V> inline auto m_le(V a, V b) { return V_LE(a, b); }
template <class V> inline auto m_ge(V a, V b) { return V_GE(a, b); }
template <class V> inline auto m_ilt(V a, V b) { return V_LT(a, b); }
template <class V> inline auto m_ile(V a, V b) { return V_LE(a, b); }
template <class V> inline auto m_ige(V a, V b) { return V_GE(a, b); }
template <class V> inline auto m_nonzero(V a) { return V_NE0(a); }
template <class M, class V> inline V m_sel(M m, V a, V b) { return V_SEL(m, a, b); }
template <class M, class V> inline V m_seli(M m, V a, V b) { return V_SEL(m, a, b); }
inline void m_stori(int32_t *p, lmask m, vi v) { vist(p, V_SEL(m, v, vild(p))); }
inline vi m_lanes(lmask m) { return m; }
inline bool m_any(lmask m) { return vany(m); }
inline uint32_t m_bits(lmask m) {
#if defined(__AVX__)
    return (uint32_t)_mm256_movemask_ps((__m256)m);
#else
    uint32_t bits = 0;
    for (int l = 0; l < VW; ++l) bits |= (uint32_t)(m[l] != 0) << l;
    return bits;
#endif
}
inline int m_count(lmask m) { return __builtin_popcount(m_bits(m)); }
#ifndef STEALTH_NS_NATIVE16
// the tests and selects of a Pair, half by half
#define STEALTH_NS_PAIR_TEST(name)                                                                     \
    template <class V> inline auto name(Pair<V> x, Pair<V> y) {                                        \
        return Pair<decltype(name(x.a, y.a))>{name(x.a, y.a), name(x.b, y.b)};                         \
    }
STEALTH_NS_PAIR_TEST(m_le)
STEALTH_NS_PAIR_TEST(m_ge)
STEALTH_NS_PAIR_TEST(m_ilt)
STEALTH_NS_PAIR_TEST(m_ile)
STEALTH_NS_PAIR_TEST(m_ige)
#undef STEALTH_NS_PAIR_TEST
template <class V> inline auto m_nonzero(Pair<V> x) { return Pair<decltype(m_nonzero(x.a))>{m_nonzero(x.a), m_nonzero(x.b)}; }
template <class M, class V> inline Pair<V> m_sel(Pair<M> m, Pair<V> x, Pair<V> y) { return {m_sel(m.a, x.a, y.a), m_sel(m.b, x.b, y.b)}; }
template <class M, class V> inline Pair<V> m_seli(Pair<M> m, Pair<V> x, Pair<V> y) { return {m_seli(m.a, x.a, y.a), m_seli(m.b, x.b, y.b)}; }
#endif
inline vi16 m_lanes16(lmask16 m) { return m; }
inline bool m_any16(lmask16 m) { return m_any(vlo(m) | vhi(m)); }  // one test of both halves
inline int m_count16(lmask16 m) { return m_count(vlo(m)) + m_count(vhi(m)); }
inline lmask m_lo8(lmask16 m) { return vlo(m); }
inline lmask m_hi8(lmask16 m) { return vhi(m); }
#endif

#if defined(__AVX512VL__) && defined(__AVX512DQ__)
// Four blocks at a time (AVX-512 only): two 16-lane vectors, the first holding blocks 0-1 and the
// second blocks 2-3, their lane masks in one 32-bit word (bits 0-15 the first vector's).  Each
// operation is applied to both halves, lane by lane as on one block.
#define STEALTH_NS_FOUR_BLOCKS 1
using vf32 = Pair<vf16>;
using vi32 = Pair<vi16>;
typedef uint32_t lmask32;
inline lmask32 m_join(lmask16 lo, lmask16 hi) { return (uint32_t)lo | (uint32_t)hi << 16; }
inline lmask16 m_lo(lmask32 m) { return (lmask16)m; }
inline lmask16 m_hi(lmask32 m) { return (lmask16)(m >> 16); }
inline lmask32 m_le(vf32 x, vf32 y) { return m_join(m_le(x.a, y.a), m_le(x.b, y.b)); }
inline lmask32 m_ge(vf32 x, vf32 y) { return m_join(m_ge(x.a, y.a), m_ge(x.b, y.b)); }
inline lmask32 m_ilt(vi32 x, vi32 y) { return m_join(m_ilt(x.a, y.a), m_ilt(x.b, y.b)); }
inline lmask32 m_ile(vi32 x, vi32 y) { return m_join(m_ile(x.a, y.a), m_ile(x.b, y.b)); }
inline lmask32 m_ige(vi32 x, vi32 y) { return m_join(m_ige(x.a, y.a), m_ige(x.b, y.b)); }
inline lmask32 m_nonzero(vi32 x) { return m_join(m_nonzero(x.a), m_nonzero(x.b)); }
inline vf32 m_sel(lmask32 m, vf32 x, vf32 y) { return {m_sel(m_lo(m), x.a, y.a), m_sel(m_hi(m), x.b, y.b)}; }
inline vi32 m_seli(lmask32 m, vi32 x, vi32 y) { return {m_seli(m_lo(m), x.a, y.a), m_seli(m_hi(m), x.b, y.b)}; }
#endif

// exp(x), lane-wise: Cody-Waite range reduction + Cephes' degree-6 polynomial
// (~1 ulp where it matters), exp(0) == 1 exactly, exp(x) <= 1 for x <= 0, 0 below
// -87.  Inlined and vectorised (glibc's expf is a call per pixel); used by both
// forward and backward so that they take identical decisions.  gsplat's CUDA
// kernels use the approximate __expf as well.
template <class F> inline F vexp(F x) {
    using I = decltype(V_LT(x, x));
    const I tiny = V_LT(x, bcast<F>(-87.0f));
    x = V_SEL(tiny, bcast<F>(-87.0f), x);
    x = V_SEL(V_GT(x, bcast<F>(88.0f)), bcast<F>(88.0f), x);
    const F magic = bcast<F>(12582912.f);
    const F kf = (x * 1.44269504088896341f + magic) - magic;
    F r = x - kf * 0.693359375f;
    r = r - kf * -2.12194440e-4f;
    F p = bcast<F>(1.9875691500e-4f);
    p = p * r + 1.3981999507e-3f;
    p = p * r + 8.3334519073e-3f;
    p = p * r + 4.1665795894e-2f;
    p = p * r + 1.6666665459e-1f;
    p = p * r + 5.0000001201e-1f;
    p = p * (r * r) + r + 1.0f;
    const I k = __builtin_convertvector(kf, I);
    const I bits = (k + 127) << 23;
    const F res = p * (F)bits;
    return V_SEL(tiny, bcast<F>(0.f), res);
}

template <class V> inline Pair<V> vexp(Pair<V> x) { return {vexp(x.a), vexp(x.b)}; }

#ifdef STEALTH_NS_FOUR_BLOCKS
template <> inline vf32 bcast<vf32>(float a) { return {bcast<vf16>(a), bcast<vf16>(a)}; }
#endif

// sigma and alpha of 8 or 16 pixels: pixel centres px, row offsets dy.
// Shared by forward and backward so that both take identical decisions.
template <class F> struct BlockEval {
    F dx, sigma, vis, alpha;
    decltype(m_ge(F{}, F{})) pass;  // sigma >= 0 && alpha >= 1/255
};

template <class F>
inline BlockEval<F> eval_block(float mx, float ca, float cb, float cc, float op, F dy, F px) {
    BlockEval<F> e;
    e.dx = mx - px;
    const F cdd = cc * dy * dy;
    e.sigma = 0.5f * (ca * e.dx * e.dx + cdd) + cb * e.dx * dy;
    e.vis = vexp(-e.sigma);
    e.alpha = vmin(op * e.vis, bcast<F>(kAlphaMax));
    e.pass = m_ge(e.sigma, F{}) & m_ge(e.alpha, bcast<F>(kAlphaMin));
    return e;
}

// ---------------------------------------------------------------------------
// Per-Gaussian footprint: the pixels that may satisfy alpha >= 1/255 lie in
// the ellipse {sigma <= t}, t = log(255 * opacity).  We use a slightly larger
// threshold teff (absorbing the float rounding of sigma and of the pixel
// offsets) and visit, row by row, the column span of that ellipse (plus
// kSpanPad).  Every visited pixel is then tested with the exact float formula,
// so the footprint only bounds the work.  Computed once per Gaussian (in
// double), used by every tile it intersects, in forward and backward.
// Non-positive-definite or non-finite conics fall back to a full-tile scan.
// ---------------------------------------------------------------------------
enum : int32_t { kSkip = 0, kFull = 1, kEllipse = 2 };
// Extra pixels on each side of the computed spans: covers the float rounding of
// the span computation (errors ~1e-4 px for coordinates < 1e3 px; the teff margin
// already covers the rounding of sigma itself).
constexpr float kSpanPad = 0.05f;
// Software prefetch distance (in list entries) for the Gaussian records of a tile's list.
constexpr int64_t kPrefetch = 4;

struct GPrep {
    float mx, my, a, b, c, o;
    float two_a_teff;  // 2 a teff
    float det;         // a c - b^2
    float inv_a, b_over_a;
    float ext_y;       // |dy| extent of the enlarged ellipse
    int32_t kind;      // kSkip (opacity < 1/255: alpha < 1/255 everywhere), kFull, kEllipse
};

inline GPrep make_prep(const float *m2, const float *con, float o_f, float coord_scale, bool cull) {
    GPrep g;
    g.mx = m2[0];
    g.my = m2[1];
    g.a = con[0];
    g.b = con[1];
    g.c = con[2];
    g.o = o_f;
    g.two_a_teff = g.det = g.inv_a = g.b_over_a = g.ext_y = 0.f;
    // alpha <= opacity (exp(-sigma) <= 1 when sigma >= 0): nothing passes 1/255.
    if (o_f < kAlphaMin) {
        g.kind = kSkip;
        return g;
    }
    g.kind = kFull;
    if (!cull) return g;
    const double a = g.a, b = g.b, c = g.c, o = o_f;
    const double det = a * c - b * b;
    if (!(a > 0.0) || !(c > 0.0) || !(det > 0.0) || !std::isfinite(det) || !std::isfinite(o) ||
        !std::isfinite((double)g.mx) || !std::isfinite((double)g.my))
        return g;  // full-tile scan
    const double t = std::log(255.0 * o);
    const double lmax = 0.5 * (a + c) + std::sqrt(0.25 * (a - c) * (a - c) + b * b);
    const double lmin = det / lmax;
    // |0.5 a dx^2| + |0.5 c dy^2| + |b dx dy| <= kappa * sigma: bounds the float error of sigma
    const double kappa = (std::max(a, c) + std::fabs(b)) / lmin;
    // rounding of dx = mx - px (float subtraction of coordinates of magnitude ~ coord_scale)
    const double grad = lmax * std::sqrt(2.0 * (std::fabs(t) + 1.0) / lmin);
    const double dpad =
        4.0 * grad * 1.2e-7 * (coord_scale + std::fabs((double)g.mx) + std::fabs((double)g.my));
    const double teff = t + 1e-6 * kappa * (std::fabs(t) + 1.0) + 1e-4 * (1.0 + std::fabs(t)) + dpad;
    const double ext = std::sqrt(2.0 * a * teff / det);
    if (!std::isfinite(teff) || !std::isfinite(ext) || ext > 1e7) return g;
    g.kind = kEllipse;
    g.two_a_teff = (float)(2.0 * a * teff);
    g.det = (float)det;
    g.inv_a = (float)(1.0 / a);
    g.b_over_a = (float)(b / a);
    g.ext_y = (float)ext;
    return g;
}

// Rows [y0, y1) of the tile rows [ty0, ty1) that the Gaussian may touch.
inline void prep_rows(const GPrep &g, int ty0, int ty1, int &y0, int &y1) {
    if (g.kind != kEllipse) {
        y0 = ty0;
        y1 = ty1;
        return;
    }
    const float lo = std::ceil(g.my - g.ext_y - 0.5f - kSpanPad);
    const float hi = std::floor(g.my + g.ext_y - 0.5f + kSpanPad) + 1.f;  // exclusive
    y0 = lo <= (float)ty0 ? ty0 : (lo >= (float)ty1 ? ty1 : (int)lo);
    y1 = hi >= (float)ty1 ? ty1 : (hi <= (float)ty0 ? ty0 : (int)hi);
    if (y1 < y0) y1 = y0;
}

// The rows [y0, y1) of the tile that the Gaussian may touch and, for each (tile-local row r = i -
// y_base), its tile-local pixel columns [lo[r], hi[r]): for pixel centre y = i + 0.5,
//   0.5 a dx^2 + b dy dx + 0.5 c dy^2 <= teff  <=>  px in centre -+ sqrt(2 a teff - det dy^2) / a.
// Vectorised over rows (VW at a time; lo/hi hold at least ts + VW entries); every lane evaluates the
// expressions a scalar per-row loop would, so the spans do not depend on the vectorisation.
inline void prep_spans(
    const GPrep &g, int x_base, int tx1, int y_base, int ty1, int &y0, int &y1, int32_t *lo, int32_t *hi
) {
    prep_rows(g, y_base, ty1, y0, y1);
    if (g.kind != kEllipse) {
        for (int r = y0 - y_base; r < y1 - y_base; ++r) {
            lo[r] = 0;
            hi[r] = tx1 - x_base;
        }
        return;
    }
    const vi lane = {0, 1, 2, 3, 4, 5, 6, 7};
    const vf tx0f = vset((float)x_base), tx1f = vset((float)tx1);
    for (int i = y0; i < y1; i += VW) {
        const vf dy = g.my - (__builtin_convertvector(lane + i, vf) + 0.5f);
        const vf disc = g.two_a_teff - g.det * dy * dy;
        const vi inside = V_GE(disc, vset(0.f));  // false for NaN too
        const vf s = vsqrt(vsel(inside, disc, vset(0.f))) * g.inv_a;
        const vf centre = g.mx + g.b_over_a * dy;
        const vf flo = vceil(centre - s - 0.5f - kSpanPad);
        const vf fhi = vfloor(centre + s - 0.5f + kSpanPad) + 1.f;  // exclusive
        const vf clo = vsel(V_LE(flo, tx0f), tx0f, vsel(V_GE(flo, tx1f), tx1f, flo));
        const vf chi = vsel(V_GE(fhi, tx1f), tx1f, vsel(V_LE(fhi, tx0f), tx0f, fhi));
        vi j0 = __builtin_convertvector(clo, vi) - x_base, j1 = __builtin_convertvector(chi, vi) - x_base;
        j1 = V_SEL(V_LT(j1, j0), j0, j1);
        j0 = V_SEL(inside, j0, viset(0));
        j1 = V_SEL(inside, j1, viset(0));
        vist(lo + (i - y_base), j0);
        vist(hi + (i - y_base), j1);
    }
}

// One VW-pixel block of a Gaussian's footprint in a tile: its offset o in the tile state, its first
// tile-local column b, the pixel-centre offset dy of its row and the row's span [lx0, lx1).
struct Block {
    int32_t o, b;
    float dy;
    int32_t lx0, lx1;
};

// U blocks of a list in one vector (U = 1: 8 lanes, U = 2: 16): reading and writing their pixels'
// tile state, their per-lane columns, spans and row offsets, and adding a 16-lane contribution to an
// 8-lane sum as two 8-lane additions in list order (the first block's, then the second's), which
// keeps every sum bitwise that of one block at a time.
// x + 0.5 of tile-local columns lx in a tile starting at column x_base
template <class I> inline auto pixel_centres(I lx, int x_base) { return vcvt(lx + x_base) + 0.5f; }
template <int U> struct Blocks;
template <> struct Blocks<1> {
    using F = vf;
    using I = vi;
    using M = lmask;
    static F ld(const float *p, const Block *b) { return vld(p + b[0].o); }
    static void st(float *p, const Block *b, F v) { vst(p + b[0].o, v); }
    static I ldi(const int32_t *p, const Block *b) { return vild(p + b[0].o); }
    static void sti(int32_t *p, const Block *b, I v) { vist(p + b[0].o, v); }
    static void stmi(int32_t *p, const Block *b, M m, I v) { m_stori(p + b[0].o, m, v); }
    static I col(const Block *b) { return vi{0, 1, 2, 3, 4, 5, 6, 7} + b[0].b; }
    static I lx0(const Block *b) { return viset(b[0].lx0); }
    static I lx1(const Block *b) { return viset(b[0].lx1); }
    static F dy(const Block *b) { return vset(b[0].dy); }
    static F px(I lx, int x_base) { return pixel_centres(lx, x_base); }
    static I bci(int32_t a) { return viset(a); }
    static void add(vf &sum, F c) { sum += c; }
    static bool any(M m) { return m_any(m); }
    static int count(M m) { return m_count(m); }
    static I lanes(M m) { return m_lanes(m); }
};
template <> struct Blocks<2> {
    using F = vf16;
    using I = vi16;
    using M = lmask16;
    static F ld(const float *p, const Block *b) { return vcat(vld(p + b[0].o), vld(p + b[1].o)); }
    static void st(float *p, const Block *b, F v) {
        vst(p + b[0].o, vlo(v));
        vst(p + b[1].o, vhi(v));
    }
    static I ldi(const int32_t *p, const Block *b) { return vcat(vild(p + b[0].o), vild(p + b[1].o)); }
    static void sti(int32_t *p, const Block *b, I v) {
        vist(p + b[0].o, vlo(v));
        vist(p + b[1].o, vhi(v));
    }
    static void stmi(int32_t *p, const Block *b, M m, I v) {
        m_stori(p + b[0].o, m_lo8(m), vlo(v));
        m_stori(p + b[1].o, m_hi8(m), vhi(v));
    }
    static I col(const Block *b) { return vcat(Blocks<1>::col(b), Blocks<1>::col(b + 1)); }
    static I lx0(const Block *b) { return vcat(viset(b[0].lx0), viset(b[1].lx0)); }
    static I lx1(const Block *b) { return vcat(viset(b[0].lx1), viset(b[1].lx1)); }
    static F dy(const Block *b) { return vcat(vset(b[0].dy), vset(b[1].dy)); }
    static F px(I lx, int x_base) { return pixel_centres(lx, x_base); }
    static I bci(int32_t a) { return vcat(viset(a), viset(a)); }
    static void add(vf &sum, F c) { sum = (sum + vlo(c)) + vhi(c); }
    static bool any(M m) { return m_any16(m); }
    static int count(M m) { return m_count16(m); }
    static I lanes(M m) { return m_lanes16(m); }
};

#ifdef STEALTH_NS_FOUR_BLOCKS
template <> struct Blocks<4> {
    using F = vf32;
    using I = vi32;
    using M = lmask32;
    using H = Blocks<2>;
    static F ld(const float *p, const Block *b) { return {H::ld(p, b), H::ld(p, b + 2)}; }
    static void st(float *p, const Block *b, F v) {
        H::st(p, b, v.a);
        H::st(p, b + 2, v.b);
    }
    static I ldi(const int32_t *p, const Block *b) { return {H::ldi(p, b), H::ldi(p, b + 2)}; }
    static void sti(int32_t *p, const Block *b, I v) {
        H::sti(p, b, v.a);
        H::sti(p, b + 2, v.b);
    }
    static void stmi(int32_t *p, const Block *b, M m, I v) {
        H::stmi(p, b, m_lo(m), v.a);
        H::stmi(p, b + 2, m_hi(m), v.b);
    }
    static I col(const Block *b) { return {H::col(b), H::col(b + 2)}; }
    static I lx0(const Block *b) { return {H::lx0(b), H::lx0(b + 2)}; }
    static I lx1(const Block *b) { return {H::lx1(b), H::lx1(b + 2)}; }
    static F dy(const Block *b) { return {H::dy(b), H::dy(b + 2)}; }
    static F px(I lx, int x_base) { return {H::px(lx.a, x_base), H::px(lx.b, x_base)}; }
    static I bci(int32_t a) { return {H::bci(a), H::bci(a)}; }
    static void add(vf &sum, F c) {
        H::add(sum, c.a);
        H::add(sum, c.b);
    }
    static bool any(M m) { return m != 0; }
    static int count(M m) { return __builtin_popcount(m); }
    static I lanes(M m) { return {m_lanes16(m_lo(m)), m_lanes16(m_hi(m))}; }
};
#endif

// Blocks per call of the rasterizer's per-block body.  The backward's body is one long chain of
// dependent operations per block (sigma, the exp polynomial, the division, the gradient terms): two
// blocks at a time leave the processor waiting on it, four let it overlap twice the work.  The
// forward's shorter body does not gain from four, so it takes two.
// Where a register holds 4 floats (SSE, NEON) an 8-pixel block already takes two registers, and one
// block at a time is the faster choice on SSE2's 16 registers (NEON's 32: not measured).  Timings:
// docs/cpu_rasterizer.md.
#if STEALTH_NS_FLOAT_LANES < 8
constexpr int kForwardBlocks = 1;
constexpr int kBackwardBlocks = 1;
#else
constexpr int kForwardBlocks = 2;
#ifdef STEALTH_NS_FOUR_BLOCKS
constexpr int kBackwardBlocks = 4;
#else
constexpr int kBackwardBlocks = 2;
#endif
#endif

// Spreads the 8 bits of x to the even bits of a 16-bit word.
inline uint32_t spread8(uint32_t x) {
    x = (x | (x << 4)) & 0x0F0Fu;
    x = (x | (x << 2)) & 0x3333u;
    return (x | (x << 1)) & 0x5555u;
}

// The blocks of a Gaussian's footprint in a tile, row by row and left to right, handed to
// body(std::integral_constant<int, U>, blocks) MaxU at a time (4 only where Blocks<4> exists, with
// AVX-512), then two at a time (U = 2) and the last one alone (U = 1) when their count is odd.
// Per-thread scratch for the row spans and the block list.
class BlockVisitor {
  public:
    BlockVisitor(int ts, int stride)
        : ts_(ts), stride_(stride), spans_(2 * (size_t)(ts + VW)), blocks_((size_t)ts * (stride / VW) + 2) {}

    template <int MaxU, class Body>
    void visit(const GPrep &g, int x_base, int tx1, int y_base, int ty1, Body &&body) {
        int32_t *lo = spans_.data(), *hi = lo + ts_ + VW;
        int y0, y1;
        prep_spans(g, x_base, tx1, y_base, ty1, y0, y1, lo, hi);
        if (stride_ == 2 * VW) {
            visit_two_per_row<MaxU>(g, y_base, y0, y1, lo, hi, body);
            return;
        }
        Block *blocks = blocks_.data();
        int nb = 0;
        for (int i = y0; i < y1; ++i) {
            const int r = i - y_base;
            const float dy = g.my - ((float)i + 0.5f);
            for (int b = lo[r] / VW * VW; b < hi[r]; b += VW) blocks[nb++] = {r * stride_ + b, b, dy, lo[r], hi[r]};
        }
        int k = 0;
        if constexpr (MaxU == 1) {
            for (; k < nb; ++k) body(std::integral_constant<int, 1>{}, blocks + k);
        } else {
            if constexpr (MaxU >= 4)
                for (; k + 4 <= nb; k += 4) body(std::integral_constant<int, 4>{}, blocks + k);
            for (; k + 2 <= nb; k += 2) body(std::integral_constant<int, 2>{}, blocks + k);
            if (k < nb) body(std::integral_constant<int, 1>{}, blocks + k);
        }
    }

  private:
    // Tiles of 9-16 pixels (gsplat's default is 16): a row has two blocks, columns [0, 8) and [8, 16).
    // The blocks in use are the set bits of one word, bit 2 r + h for row r, half h, computed for
    // all rows at once instead of row by row (the listing, spans included, is a large part of the
    // forward: docs/cpu_rasterizer.md).
    template <int MaxU, class Body>
    void visit_two_per_row(const GPrep &g, int y_base, int y0, int y1, const int32_t *lo, const int32_t *hi, Body &body) {
        const vi lane = {0, 1, 2, 3, 4, 5, 6, 7};
        uint32_t used = 0;
        for (int q = 0; q < 2; ++q) {  // rows 8 q .. 8 q + 7 (those outside [y0, y1) hold stale spans)
            const vi row = lane + (y_base + VW * q);
            const vi l = vild(lo + VW * q), h = vild(hi + VW * q);
            const lmask some = m_ige(row, viset(y0)) & m_ilt(row, viset(y1)) & m_ilt(l, h);
            const lmask left = some & m_ilt(l, viset(VW)), right = some & m_ilt(viset(VW), h);
            used |= (spread8(m_bits(left)) | spread8(m_bits(right)) << 1) << (2 * VW * q);
        }
        auto block = [&](int code) {
            const int r = code >> 1, b = (code & 1) * VW;
            return Block{r * stride_ + b, b, g.my - ((float)(y_base + r) + 0.5f), lo[r], hi[r]};
        };
        Block list[4];
        if constexpr (MaxU >= 4) {
            while (__builtin_popcount(used) >= 4) {
                for (int k = 0; k < 4; ++k) {
                    list[k] = block(__builtin_ctz(used));
                    used &= used - 1;
                }
                body(std::integral_constant<int, 4>{}, list);
            }
        }
        if constexpr (MaxU == 1) {
            for (; used; used &= used - 1) {
                list[0] = block(__builtin_ctz(used));
                body(std::integral_constant<int, 1>{}, list);
            }
            return;
        }
        while (used) {
            list[0] = block(__builtin_ctz(used));
            used &= used - 1;
            if (!used) {
                body(std::integral_constant<int, 1>{}, list);
                return;
            }
            list[1] = block(__builtin_ctz(used));
            used &= used - 1;
            body(std::integral_constant<int, 2>{}, list);
        }
    }

    int ts_, stride_;
    std::vector<int32_t> spans_;
    std::vector<Block> blocks_;
};

// Parallel pre-pass over the Gaussians that some tile list holds (in training often under half of
// the C*N: the rest have radius 0).  Rows of the others are left uninitialised: nothing reads them.
std::unique_ptr<GPrep[]> prepare(
    int64_t CN, const float *means2d, const float *conics, const float *opacities, float coord_scale, bool cull,
    const int32_t *flatten_ids, int64_t n_isects, int n_threads
) {
    std::unique_ptr<GPrep[]> prep(new GPrep[(size_t)CN]);
    std::vector<uint8_t> listed((size_t)CN, 0);
    for (int64_t k = 0; k < n_isects; ++k) listed[flatten_ids[k]] = 1;
#pragma omp parallel for schedule(static) num_threads(n_threads)
    for (int64_t i = 0; i < CN; ++i)
        if (listed[i]) prep[i] = make_prep(means2d + 2 * i, conics + 3 * i, opacities[i], coord_scale, cull);
    return prep;
}

inline void atomic_add(float *addr, float v) {
#pragma omp atomic update
    *addr += v;
}

struct TileGeom {
    int W, H, ts, tiles_x, tiles_y;
};

inline void tile_range(
    const int32_t *offsets, int64_t cam, int64_t tile, int64_t C, int64_t n_tiles, int64_t n_isects,
    int64_t &start, int64_t &end
) {
    const int64_t flat = cam * n_tiles + tile;
    start = offsets[flat];
    end = (flat == C * n_tiles - 1) ? n_isects : (int64_t)offsets[flat + 1];
}

// The pixel rectangle [x0, x1) x [y0, y1) of a (camera, tile) task, clipped to the image.
struct TaskPixels {
    int64_t cam, tile;
    int x0, y0, x1, y1;
};

inline TaskPixels task_pixels(int64_t task, const TileGeom &g) {
    const int64_t n_tiles = (int64_t)g.tiles_x * g.tiles_y;
    TaskPixels r;
    r.cam = task / n_tiles;
    r.tile = task % n_tiles;
    r.x0 = (int)(r.tile % g.tiles_x) * g.ts;
    r.y0 = (int)(r.tile / g.tiles_x) * g.ts;
    r.x1 = std::min(r.x0 + g.ts, g.W);
    r.y1 = std::min(r.y0 + g.ts, g.H);
    return r;
}

// Reads one byte of every cache line of the rectangle r of a per-pixel array (`bytes` bytes per
// pixel, rows of g.W pixels; camera r.cam of a [C, H, W, ...] array), so that the task that reads or
// writes those pixels later finds them in the cache.  Each of the rectangle's rows lies in another
// page.  Read one pixel at a time when the task comes, they are cache misses the processor cannot
// overlap (the loop over a row's pixels fills its reorder window).  Plain loads, not
// __builtin_prefetch: prefetch hints are dropped, most likely on a TLB miss (docs/cpu_rasterizer.md).
inline void touch_rect(const void *base, const TaskPixels &r, const TileGeom &g, int bytes) {
    const char *p = static_cast<const char *>(base) + r.cam * (int64_t)g.H * g.W * bytes;
    uint32_t sink = 0;
    for (int i = r.y0; i < r.y1; ++i) {
        const char *a = p + ((int64_t)i * g.W + r.x0) * bytes, *b = p + ((int64_t)i * g.W + r.x1) * bytes;
        for (const char *q = (const char *)((uintptr_t)a & ~(uintptr_t)63); q < b; q += 64) sink += *(const uint8_t *)q;
    }
    asm volatile("" : : "r"(sink));  // keeps the loads
}

// A per-pixel array for touch_rect: its data and bytes per pixel.
struct PixelArray {
    const void *data;
    int bytes;
};

// The tasks of `order`, handed out one at a time in that order (as schedule(dynamic, 1) does).  A
// thread claims its next task before it runs the current one and touches that next task's pixels in
// `arrays` meanwhile.  Which thread runs a task never changes its result.
class TaskQueue {
  public:
    TaskQueue(const std::vector<int32_t> &order, const TileGeom &g, std::vector<PixelArray> arrays)
        : order_(order), g_(g), arrays_(std::move(arrays)) {}

    // The calling thread's next task in r (false when none is left); `ahead` is the thread's task
    // claimed in advance, -1 before its first call.
    bool next(int64_t &ahead, TaskPixels &r) {
        const int64_t n = (int64_t)order_.size(), t = ahead >= 0 ? ahead : claim();
        if (t >= n) return false;
        ahead = claim();
        if (ahead < n) {
            const TaskPixels a = task_pixels(order_[ahead], g_);
            for (const PixelArray &p : arrays_) touch_rect(p.data, a, g_, p.bytes);
        }
        r = task_pixels(order_[t], g_);
        return true;
    }

  private:
    int64_t claim() { return next_.fetch_add(1, std::memory_order_relaxed); }

    const std::vector<int32_t> &order_;
    const TileGeom &g_;
    const std::vector<PixelArray> arrays_;
    std::atomic<int64_t> next_{0};
};

// The (camera, tile) tasks, longest list first: handed out one at a time, the threads then finish
// together (longest-processing-time-first) instead of one thread taking a long tile last.  Which
// thread runs a task never changes its result.
std::vector<int32_t> tasks_by_cost(const int32_t *offsets, int64_t n_tasks, int64_t n_isects) {
    std::vector<int32_t> order((size_t)n_tasks);
    std::iota(order.begin(), order.end(), 0);
    auto cost = [&](int32_t t) { return (t + 1 < n_tasks ? (int64_t)offsets[t + 1] : n_isects) - offsets[t]; };
    std::stable_sort(order.begin(), order.end(), [&](int32_t a, int32_t b) { return cost(a) > cost(b); });
    return order;
}

// ---------------------------------------------------------------------------
// Forward
// ---------------------------------------------------------------------------
template <int DT>
void fwd_impl(
    int64_t C, int64_t N, int Drt, const TileGeom &g, int64_t n_isects, bool cull,
    const float *__restrict__ means2d, const float *__restrict__ conics, const float *__restrict__ colors,
    const float *__restrict__ opacities, const float *__restrict__ backgrounds,
    const int32_t *__restrict__ offsets, const int32_t *__restrict__ flatten_ids,
    float *__restrict__ out_colors, float *__restrict__ out_alphas, float *__restrict__ out_T,
    int32_t *__restrict__ out_last, float *__restrict__ isect_w, int n_threads
) {
    const std::unique_ptr<GPrep[]> prep_v = prepare(
        C * N, means2d, conics, opacities, (float)(g.W + g.H), cull, flatten_ids, n_isects, n_threads
    );
    const GPrep *__restrict__ prep = prep_v.get();
    const int D = DT > 0 ? DT : Drt;
    const int ts = g.ts;
    const int stride = (ts + VW - 1) / VW * VW;  // padded row length of the per-tile state
    const int npad = stride * ts;
    const int64_t n_tiles = (int64_t)g.tiles_x * g.tiles_y;
    const int64_t n_tasks = C * n_tiles;
    const std::vector<int32_t> task_order = tasks_by_cost(offsets, n_tasks, n_isects);
    const int64_t HW = (int64_t)g.H * g.W;
    TaskQueue queue(task_order, g, {{out_T, 4}, {out_alphas, 4}, {out_last, 4}, {out_colors, 4 * D}});  // outputs

#pragma omp parallel num_threads(n_threads)
    {
        // per-thread tile state, structure of arrays: T, last index, done mask, colour planes
        std::vector<float> T_buf(npad), col_buf((size_t)npad * D);
        std::vector<int32_t> last_buf(npad), done_buf(npad);
        float *__restrict__ Tp = T_buf.data();
        float *__restrict__ colp = col_buf.data();
        int32_t *__restrict__ lastp = last_buf.data();
        int32_t *__restrict__ donep = done_buf.data();
        BlockVisitor visitor(ts, stride);

        TaskPixels r;
        for (int64_t ahead = -1; queue.next(ahead, r);) {
            const int64_t cam = r.cam, tile = r.tile;
            const int x_base = r.x0, y_base = r.y0, tx1 = r.x1, ty1 = r.y1;
            if (tx1 <= x_base || ty1 <= y_base) continue;  // tile fully outside the image
            int64_t start, end;
            tile_range(offsets, cam, tile, C, n_tiles, n_isects, start, end);

            std::fill(Tp, Tp + npad, 1.f);
            std::fill(colp, colp + (size_t)npad * D, 0.f);
            std::fill(lastp, lastp + npad, (int32_t)-1);
            std::fill(donep, donep + npad, (int32_t)0);
            int active = (tx1 - x_base) * (ty1 - y_base);

            for (int64_t idx = start; idx < end && active > 0; ++idx) {
                const int64_t gi = flatten_ids[idx];
                if (idx + kPrefetch < end) {
                    const int64_t gn = flatten_ids[idx + kPrefetch];
                    __builtin_prefetch(prep + gn);
                    __builtin_prefetch(colors + gn * D);
                }
                const GPrep &gp = prep[gi];
                if (gp.kind == kSkip) continue;
                const float mx = gp.mx, ca = gp.a, cb = gp.b, cc = gp.c, op = gp.o;  // dy: from the block
                const float *__restrict__ cptr = colors + gi * D;
                vf wsum{};  // the Gaussian's T * alpha summed over the tile's pixels (isect_w only)
                visitor.visit<kForwardBlocks>(gp, x_base, tx1, y_base, ty1, [&](auto u, const Block *b) {
                    using B = Blocks<decltype(u)::value>;
                    using F = typename B::F;
                    using I = typename B::I;
                    using M = typename B::M;
                    const I lx = B::col(b);
                    const I done = B::ldi(donep, b);
                    const M todo = m_ige(lx, B::lx0(b)) & m_ilt(lx, B::lx1(b)) & ~m_nonzero(done);
                    if (!B::any(todo)) return;
                    const F px = B::px(lx, x_base);
                    const BlockEval<F> e = eval_block(mx, ca, cb, cc, op, B::dy(b), px);
                    const M valid = todo & e.pass;
                    const F T = B::ld(Tp, b);
                    const F next_T = T * (1.f - e.alpha);
                    const M term = valid & m_le(next_T, bcast<F>(kTransmittanceMin));  // exclusive stop
                    const M contrib = valid & ~term;
                    if (B::any(term)) {
                        B::sti(donep, b, done | B::lanes(term));
                        active -= B::count(term);
                    }
                    // zero weight where the lane does not contribute: adds exactly +-0 (finite colours)
                    const F vis = m_sel(contrib, e.alpha * T, F{});
                    B::st(Tp, b, m_sel(contrib, next_T, T));
                    B::stmi(lastp, b, contrib, B::bci((int32_t)idx));
                    for (int k = 0; k < D; ++k) {
                        float *__restrict__ cp = colp + (size_t)k * npad;
                        B::st(cp, b, B::ld(cp, b) + cptr[k] * vis);
                    }
                    if (isect_w) B::add(wsum, vis);
                });
                if (isect_w) isect_w[idx] = vsum(wsum);
            }

            const float *bg = backgrounds ? backgrounds + cam * D : nullptr;
            for (int i = y_base; i < ty1; ++i) {
                for (int j = x_base; j < tx1; ++j) {
                    const int p = (i - y_base) * stride + (j - x_base);
                    const int64_t pix = cam * HW + (int64_t)i * g.W + j;
                    const float T = Tp[p];
                    out_T[pix] = T;
                    out_alphas[pix] = 1.f - T;
                    out_last[pix] = lastp[p];
                    float *oc = out_colors + pix * D;
                    if (bg) {
                        for (int k = 0; k < D; ++k) oc[k] = colp[(size_t)k * npad + p] + T * bg[k];
                    } else {
                        for (int k = 0; k < D; ++k) oc[k] = colp[(size_t)k * npad + p];
                    }
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------
// Backward
// ---------------------------------------------------------------------------
template <int DT>
void bwd_impl(
    int64_t C, int64_t N, int Drt, const TileGeom &g, int64_t n_isects, bool cull, int mode,
    const float *__restrict__ means2d, const float *__restrict__ conics, const float *__restrict__ colors,
    const float *__restrict__ opacities, const float *__restrict__ backgrounds,
    const int32_t *__restrict__ offsets, const int32_t *__restrict__ flatten_ids,
    const float *__restrict__ T_final, const int32_t *__restrict__ last_ids,
    const float *__restrict__ v_colors_out, const float *__restrict__ v_alphas_out,
    float *__restrict__ v_means2d, float *__restrict__ v_conics, float *__restrict__ v_colors,
    float *__restrict__ v_opacities,
    float *__restrict__ isect_buf,   // mode 0: [n_isects, 6 + D] zero-initialised
    float *__restrict__ thread_buf,  // mode 2: [n_threads, C*N, 6 + D] zero-initialised
    int n_threads
) {
    const std::unique_ptr<GPrep[]> prep_v = prepare(
        C * N, means2d, conics, opacities, (float)(g.W + g.H), cull, flatten_ids, n_isects, n_threads
    );
    const GPrep *__restrict__ prep = prep_v.get();
    const int D = DT > 0 ? DT : Drt;
    const int S = 6 + D;  // per-Gaussian gradient record: xy(2) conic(3) opacity(1) rgb(D)
    const int ts = g.ts;
    const int stride = (ts + VW - 1) / VW * VW;
    const int npad = stride * ts;
    const int64_t n_tiles = (int64_t)g.tiles_x * g.tiles_y;
    const int64_t n_tasks = C * n_tiles;
    const std::vector<int32_t> task_order = tasks_by_cost(offsets, n_tasks, n_isects);
    const int64_t HW = (int64_t)g.H * g.W;
    TaskQueue queue(task_order, g, {{T_final, 4}, {last_ids, 4}, {v_alphas_out, 4}, {v_colors_out, 4 * D}});  // inputs

#pragma omp parallel num_threads(n_threads)
    {
        std::vector<float> T_buf(npad), w_buf(npad), vout_buf((size_t)npad * D), acc_buf((size_t)npad * D);
        std::vector<int32_t> last_buf(npad);
        // a Gaussian's per-tile gradient sums in the record's order (xy, conic, opacity, colours),
        // 8 lanes each, and their totals
        std::vector<vf> terms_dyn(DT > 0 ? 0 : S);
        std::vector<float> sums_dyn(DT > 0 ? 0 : S);
        vf terms_st[DT > 0 ? 6 + DT : 1];
        float sums_st[DT > 0 ? 6 + DT : 1];
        vf *__restrict__ terms = DT > 0 ? terms_st : terms_dyn.data();
        float *__restrict__ sums = DT > 0 ? sums_st : sums_dyn.data();
        vf *__restrict__ grgb = terms + 6;
        float *__restrict__ Tp = T_buf.data();
        float *__restrict__ wp = w_buf.data();
        float *__restrict__ voutp = vout_buf.data();
        float *__restrict__ accp = acc_buf.data();
        int32_t *__restrict__ lastp = last_buf.data();
        BlockVisitor visitor(ts, stride);
        float *__restrict__ my_buf = mode == 2 ? thread_buf + (size_t)omp_get_thread_num() * C * N * S : nullptr;

        TaskPixels r;
        for (int64_t ahead = -1; queue.next(ahead, r);) {
            const int64_t cam = r.cam, tile = r.tile;
            const int x_base = r.x0, y_base = r.y0, tx1 = r.x1, ty1 = r.y1;
            if (tx1 <= x_base || ty1 <= y_base) continue;
            int64_t start, end;
            tile_range(offsets, cam, tile, C, n_tiles, n_isects, start, end);
            if (end <= start) continue;

            const float *bg = backgrounds ? backgrounds + cam * D : nullptr;
            std::fill(lastp, lastp + npad, (int32_t)-1);  // padding / outside pixels never match
            int64_t max_last = -1;
            for (int i = y_base; i < ty1; ++i) {
                for (int j = x_base; j < tx1; ++j) {
                    const int p = (i - y_base) * stride + (j - x_base);
                    const int64_t pix = cam * HW + (int64_t)i * g.W + j;
                    const float Tf = T_final[pix];
                    Tp[p] = Tf;
                    lastp[p] = last_ids[pix];
                    max_last = std::max<int64_t>(max_last, last_ids[pix]);
                    const float *vc = v_colors_out + pix * D;
                    float bgdot = 0.f;
                    for (int k = 0; k < D; ++k) {
                        voutp[(size_t)k * npad + p] = vc[k];
                        accp[(size_t)k * npad + p] = 0.f;
                    }
                    if (bg) {
                        for (int k = 0; k < D; ++k) bgdot += bg[k] * vc[k];
                    }
                    // v_alpha gets ra * T_final * (v_render_alpha - <bg, v_render_color>)
                    wp[p] = Tf * v_alphas_out[pix] - Tf * bgdot;
                }
            }
            if (max_last < start) continue;
            if (max_last >= end) max_last = end - 1;

            for (int64_t idx = max_last; idx >= start; --idx) {
                const int64_t gi = flatten_ids[idx];
                if (idx - kPrefetch >= start) {
                    const int64_t gn = flatten_ids[idx - kPrefetch];
                    __builtin_prefetch(prep + gn);
                    __builtin_prefetch(colors + gn * D);
                }
                const GPrep &gp = prep[gi];
                if (gp.kind == kSkip) continue;
                const float mx = gp.mx, ca = gp.a, cb = gp.b, cc = gp.c, op = gp.o;  // dy: from the block
                const float *__restrict__ cptr = colors + gi * D;
                for (int k = 0; k < D; ++k) grgb[k] = vset(0.f);
                vf g_ca = vset(0.f), g_cb = g_ca, g_cc = g_ca, g_x = g_ca, g_y = g_ca, g_o = g_ca;
                bool hit = false;
                // always_inline: otherwise GCC keeps this large body an out-of-line call per two blocks,
                // and the nine per-Gaussian sums above go through memory (closure references) at every call
                visitor.visit<kBackwardBlocks>(gp, x_base, tx1, y_base, ty1, [&](auto u, const Block *b) __attribute__((always_inline)) {
                    using B = Blocks<decltype(u)::value>;
                    using F = typename B::F;
                    using I = typename B::I;
                    using M = typename B::M;
                    const I lx = B::col(b);
                    const M mine =
                        m_ige(lx, B::lx0(b)) & m_ilt(lx, B::lx1(b)) & m_ile(B::bci((int32_t)idx), B::ldi(lastp, b));
                    if (!B::any(mine)) return;
                    const F px = B::px(lx, x_base);
                    const F dy = B::dy(b);
                    const BlockEval<F> e = eval_block(mx, ca, cb, cc, op, dy, px);
                    const M valid = mine & e.pass;
                    hit |= B::any(valid);
                    const F ra = 1.f / (1.f - e.alpha);
                    const F T_after = B::ld(Tp, b);
                    const F T = m_sel(valid, T_after * ra, T_after);
                    B::st(Tp, b, T);
                    // lanes that do not contribute get a zero factor: they add exactly +-0 below, which
                    // leaves the sums bitwise as they were (the operands are finite wherever the colours
                    // and upstream gradients are)
                    const F zero{};
                    const F fac = m_sel(valid, e.alpha * T, zero);
                    F v_alpha = zero;
                    for (int k = 0; k < D; ++k) {
                        const F vo = B::ld(voutp + (size_t)k * npad, b);
                        const F ac = B::ld(accp + (size_t)k * npad, b);
                        B::add(grgb[k], fac * vo);
                        v_alpha += (cptr[k] * T - ac * ra) * vo;
                    }
                    v_alpha += ra * B::ld(wp, b);
                    const M unclamped = valid & m_le(op * e.vis, bcast<F>(kAlphaMax));
                    const F vis = m_sel(unclamped, e.vis, zero);
                    const F v_sigma = -op * vis * v_alpha;
                    const F dx = e.dx;
                    B::add(g_ca, 0.5f * v_sigma * dx * dx);
                    B::add(g_cb, v_sigma * dx * dy);
                    B::add(g_cc, 0.5f * v_sigma * dy * dy);
                    B::add(g_x, v_sigma * (ca * dx + cb * dy));
                    B::add(g_y, v_sigma * (cb * dx + cc * dy));
                    B::add(g_o, vis * v_alpha);
                    for (int k = 0; k < D; ++k) {
                        float *__restrict__ acp = accp + (size_t)k * npad;
                        B::st(acp, b, B::ld(acp, b) + cptr[k] * fac);
                    }
                });
                if (!hit) continue;
                terms[0] = g_x;
                terms[1] = g_y;
                terms[2] = g_ca;
                terms[3] = g_cb;
                terms[4] = g_cc;
                terms[5] = g_o;
                vsums(terms, S, sums);
                if (mode == 0) {
                    std::memcpy(isect_buf + idx * S, sums, sizeof(float) * S);
                } else if (mode == 1) {
                    atomic_add(v_means2d + 2 * gi, sums[0]);
                    atomic_add(v_means2d + 2 * gi + 1, sums[1]);
                    atomic_add(v_conics + 3 * gi, sums[2]);
                    atomic_add(v_conics + 3 * gi + 1, sums[3]);
                    atomic_add(v_conics + 3 * gi + 2, sums[4]);
                    atomic_add(v_opacities + gi, sums[5]);
                    for (int k = 0; k < D; ++k) atomic_add(v_colors + gi * D + k, sums[6 + k]);
                } else {
                    float *r = my_buf + gi * S;
                    for (int k = 0; k < S; ++k) r[k] += sums[k];
                }
            }
        }
    }

    if (mode == 0) {
        // Deterministic reduction in intersection order; threads own disjoint ranges
        // of Gaussians (each scans the id list, adds only its own records).
        const int64_t CN = C * N;
#pragma omp parallel num_threads(n_threads)
        {
            const int nth = omp_get_num_threads(), th = omp_get_thread_num();
            const int64_t g0 = CN * th / nth, g1 = CN * (th + 1) / nth;
            for (int64_t idx = 0; idx < n_isects; ++idx) {
                const int64_t gi = flatten_ids[idx];
                if (gi < g0 || gi >= g1) continue;
                const float *r = isect_buf + idx * S;
                v_means2d[2 * gi] += r[0];
                v_means2d[2 * gi + 1] += r[1];
                v_conics[3 * gi] += r[2];
                v_conics[3 * gi + 1] += r[3];
                v_conics[3 * gi + 2] += r[4];
                v_opacities[gi] += r[5];
                float *vc = v_colors + gi * D;
                for (int k = 0; k < D; ++k) vc[k] += r[6 + k];
            }
        }
    } else if (mode == 2) {
        const int64_t CN = C * N;
#pragma omp parallel for schedule(static) num_threads(n_threads)
        for (int64_t gi = 0; gi < CN; ++gi) {
            for (int t = 0; t < n_threads; ++t) {
                const float *r = thread_buf + ((size_t)t * CN + gi) * S;
                v_means2d[2 * gi] += r[0];
                v_means2d[2 * gi + 1] += r[1];
                v_conics[3 * gi] += r[2];
                v_conics[3 * gi + 1] += r[3];
                v_conics[3 * gi + 2] += r[4];
                v_opacities[gi] += r[5];
                float *vc = v_colors + gi * D;
                for (int k = 0; k < D; ++k) vc[k] += r[6 + k];
            }
        }
    }
}

// ---------------------------------------------------------------------------
// Argument checks / dispatch
// ---------------------------------------------------------------------------
using stealth_ns::check_cpu_f32;
using stealth_ns::check_cpu_i32;

// Out-of-range offsets / ids would make the kernels read out of bounds: check them
// (O(tiles + n_isects), negligible next to the rasterization).
void validate_lists(const at::Tensor &isect_offsets, const at::Tensor &flatten_ids, int64_t CN) {
    const int32_t *off = isect_offsets.data_ptr<int32_t>();
    const int64_t n_off = isect_offsets.numel(), n = flatten_ids.numel();
    int64_t prev = 0;
    for (int64_t i = 0; i < n_off; ++i) {
        TORCH_CHECK(off[i] >= prev && off[i] <= n, "isect_offsets must be non-decreasing and <= n_isects");
        prev = off[i];
    }
    const int32_t *ids = flatten_ids.data_ptr<int32_t>();
    int32_t lo = 0, hi = -1;
    if (n > 0) lo = hi = ids[0];
    for (int64_t i = 0; i < n; ++i) {
        lo = std::min(lo, ids[i]);
        hi = std::max(hi, ids[i]);
    }
    TORCH_CHECK(n == 0 || (lo >= 0 && hi < CN), "flatten_ids out of range [0, C*N)");
}

int resolve_threads(int64_t n_threads) {
    if (n_threads > 0) return (int)n_threads;
    return std::max(1, at::get_num_threads());
}

#define STEALTH_DISPATCH_D(D, FN, ...)         \
    switch (D) {                               \
    case 1: FN<1>(__VA_ARGS__); break;         \
    case 2: FN<2>(__VA_ARGS__); break;         \
    case 3: FN<3>(__VA_ARGS__); break;         \
    case 4: FN<4>(__VA_ARGS__); break;         \
    default: FN<0>(__VA_ARGS__); break;        \
    }

}  // namespace

namespace {

// The forward's outputs (render_colors, render_alphas, last_ids, T_final), and with `weights` a fifth:
// [C, N] every Gaussian's T * alpha summed over the pixels it is blended into, each tile's sum
// written to its own intersection slot and the slots added in intersection order (deterministic).
std::vector<at::Tensor> forward_outputs(
    const at::Tensor &means2d, const at::Tensor &conics, const at::Tensor &colors,
    const at::Tensor &opacities, const std::optional<at::Tensor> &backgrounds, int64_t image_width,
    int64_t image_height, int64_t tile_size, const at::Tensor &isect_offsets,
    const at::Tensor &flatten_ids, bool cull, int64_t n_threads, bool weights
) {
    check_cpu_f32(means2d, "means2d");
    check_cpu_f32(conics, "conics");
    check_cpu_f32(colors, "colors");
    check_cpu_f32(opacities, "opacities");
    check_cpu_i32(isect_offsets, "isect_offsets");
    check_cpu_i32(flatten_ids, "flatten_ids");
    TORCH_CHECK(means2d.dim() == 3 && means2d.size(2) == 2, "means2d must be [C, N, 2]");
    const int64_t C = means2d.size(0), N = means2d.size(1);
    TORCH_CHECK(conics.dim() == 3 && conics.size(0) == C && conics.size(1) == N && conics.size(2) == 3,
                "conics must be [C, N, 3]");
    TORCH_CHECK(colors.dim() == 3 && colors.size(0) == C && colors.size(1) == N, "colors must be [C, N, D]");
    TORCH_CHECK(opacities.dim() == 2 && opacities.size(0) == C && opacities.size(1) == N,
                "opacities must be [C, N]");
    const int64_t D = colors.size(2);
    TORCH_CHECK(D >= 1, "colors must have at least one channel");
    TORCH_CHECK(tile_size >= 1, "tile_size must be positive");
    TORCH_CHECK(isect_offsets.dim() == 3 && isect_offsets.size(0) == C, "isect_offsets must be [C, th, tw]");
    const int64_t tiles_y = isect_offsets.size(1), tiles_x = isect_offsets.size(2);
    TORCH_CHECK(tiles_y * tile_size >= image_height && tiles_x * tile_size >= image_width,
                "isect_offsets grid does not cover the image");
    const float *bg = nullptr;
    if (backgrounds.has_value() && backgrounds->defined()) {
        check_cpu_f32(*backgrounds, "backgrounds");
        TORCH_CHECK(backgrounds->dim() == 2 && backgrounds->size(0) == C && backgrounds->size(1) == D,
                    "backgrounds must be [C, D]");
        bg = backgrounds->data_ptr<float>();
    }
    auto fopt = means2d.options();
    auto out_colors = at::empty({C, image_height, image_width, D}, fopt);
    auto out_alphas = at::empty({C, image_height, image_width, 1}, fopt);
    auto out_T = at::empty({C, image_height, image_width}, fopt);
    auto out_last = at::empty({C, image_height, image_width}, fopt.dtype(at::kInt));
    const int64_t n_isects = flatten_ids.numel();
    TORCH_CHECK(n_isects < (int64_t)std::numeric_limits<int32_t>::max(), "too many intersections");
    validate_lists(isect_offsets, flatten_ids, C * N);
    TileGeom g{(int)image_width, (int)image_height, (int)tile_size, (int)tiles_x, (int)tiles_y};
    const int nt = resolve_threads(n_threads);
    // a tile that stops before a Gaussian of its list never writes that Gaussian's slot: zeros
    std::vector<float> isect_w(weights ? (size_t)n_isects : 0, 0.f);
    STEALTH_DISPATCH_D(
        D, fwd_impl, C, N, (int)D, g, n_isects, cull, means2d.data_ptr<float>(), conics.data_ptr<float>(),
        colors.data_ptr<float>(), opacities.data_ptr<float>(), bg, isect_offsets.data_ptr<int32_t>(),
        flatten_ids.data_ptr<int32_t>(), out_colors.data_ptr<float>(), out_alphas.data_ptr<float>(),
        out_T.data_ptr<float>(), out_last.data_ptr<int32_t>(), weights ? isect_w.data() : nullptr, nt
    );
    if (!weights) return {out_colors, out_alphas, out_last, out_T};
    auto out_w = at::zeros({C, N}, fopt);
    float *w = out_w.data_ptr<float>();
    const int32_t *ids = flatten_ids.data_ptr<int32_t>();
    for (int64_t k = 0; k < n_isects; ++k) w[ids[k]] += isect_w[(size_t)k];
    return {out_colors, out_alphas, out_last, out_T, out_w};
}

}  // namespace

// Returns (render_colors [C,H,W,D], render_alphas [C,H,W,1], last_ids [C,H,W] int32,
//          T_final [C,H,W]).  last_ids is -1 for pixels without contributor.
std::vector<at::Tensor> rasterize_fwd(
    const at::Tensor &means2d, const at::Tensor &conics, const at::Tensor &colors,
    const at::Tensor &opacities, const std::optional<at::Tensor> &backgrounds, int64_t image_width,
    int64_t image_height, int64_t tile_size, const at::Tensor &isect_offsets,
    const at::Tensor &flatten_ids, bool cull, int64_t n_threads
) {
    return forward_outputs(
        means2d, conics, colors, opacities, backgrounds, image_width, image_height, tile_size, isect_offsets,
        flatten_ids, cull, n_threads, false
    );
}

std::vector<at::Tensor> rasterize_weights(
    const at::Tensor &means2d, const at::Tensor &conics, const at::Tensor &colors,
    const at::Tensor &opacities, const std::optional<at::Tensor> &backgrounds, int64_t image_width,
    int64_t image_height, int64_t tile_size, const at::Tensor &isect_offsets,
    const at::Tensor &flatten_ids, bool cull, int64_t n_threads
) {
    auto out = forward_outputs(
        means2d, conics, colors, opacities, backgrounds, image_width, image_height, tile_size, isect_offsets,
        flatten_ids, cull, n_threads, true
    );
    return {out[0], out[1], out[4]};
}

// Returns (v_means2d [C,N,2], v_conics [C,N,3], v_colors [C,N,D], v_opacities [C,N]).
std::vector<at::Tensor> rasterize_bwd(
    const at::Tensor &means2d, const at::Tensor &conics, const at::Tensor &colors,
    const at::Tensor &opacities, const std::optional<at::Tensor> &backgrounds, int64_t image_width,
    int64_t image_height, int64_t tile_size, const at::Tensor &isect_offsets,
    const at::Tensor &flatten_ids, const at::Tensor &T_final, const at::Tensor &last_ids,
    const at::Tensor &v_render_colors, const at::Tensor &v_render_alphas, bool cull, int64_t mode,
    int64_t n_threads
) {
    check_cpu_f32(means2d, "means2d");
    check_cpu_f32(conics, "conics");
    check_cpu_f32(colors, "colors");
    check_cpu_f32(opacities, "opacities");
    check_cpu_i32(isect_offsets, "isect_offsets");
    check_cpu_i32(flatten_ids, "flatten_ids");
    check_cpu_f32(T_final, "T_final");
    check_cpu_i32(last_ids, "last_ids");
    check_cpu_f32(v_render_colors, "v_render_colors");
    check_cpu_f32(v_render_alphas, "v_render_alphas");
    const int64_t C = means2d.size(0), N = means2d.size(1), D = colors.size(2);
    TORCH_CHECK(v_render_colors.numel() == C * image_height * image_width * D, "v_render_colors shape");
    TORCH_CHECK(v_render_alphas.numel() == C * image_height * image_width, "v_render_alphas shape");
    TORCH_CHECK(T_final.numel() == C * image_height * image_width, "T_final shape");
    TORCH_CHECK(last_ids.numel() == C * image_height * image_width, "last_ids shape");
    TORCH_CHECK(mode >= 0 && mode <= 2, "mode must be 0, 1 or 2");
    const float *bg = nullptr;
    if (backgrounds.has_value() && backgrounds->defined()) {
        check_cpu_f32(*backgrounds, "backgrounds");
        TORCH_CHECK(backgrounds->numel() == C * D, "backgrounds must be [C, D]");
        bg = backgrounds->data_ptr<float>();
    }
    TORCH_CHECK(isect_offsets.dim() == 3 && isect_offsets.size(0) == C, "isect_offsets must be [C, th, tw]");
    validate_lists(isect_offsets, flatten_ids, C * N);
    const int64_t tiles_y = isect_offsets.size(1), tiles_x = isect_offsets.size(2);
    auto fopt = means2d.options();
    auto v_means2d = at::zeros({C, N, 2}, fopt);
    auto v_conics = at::zeros({C, N, 3}, fopt);
    auto v_colors = at::zeros({C, N, D}, fopt);
    auto v_opacities = at::zeros({C, N}, fopt);
    const int64_t n_isects = flatten_ids.numel();
    const int nt = resolve_threads(n_threads);
    at::Tensor isect_buf, thread_buf;
    float *isect_ptr = nullptr, *thread_ptr = nullptr;
    if (mode == 0) {
        isect_buf = at::zeros({std::max<int64_t>(n_isects, 1), 6 + D}, fopt);
        isect_ptr = isect_buf.data_ptr<float>();
    } else if (mode == 2) {
        thread_buf = at::zeros({(int64_t)nt, std::max<int64_t>(C * N, 1), 6 + D}, fopt);
        thread_ptr = thread_buf.data_ptr<float>();
    }
    TileGeom g{(int)image_width, (int)image_height, (int)tile_size, (int)tiles_x, (int)tiles_y};
    STEALTH_DISPATCH_D(
        D, bwd_impl, C, N, (int)D, g, n_isects, cull, (int)mode, means2d.data_ptr<float>(),
        conics.data_ptr<float>(), colors.data_ptr<float>(), opacities.data_ptr<float>(), bg,
        isect_offsets.data_ptr<int32_t>(), flatten_ids.data_ptr<int32_t>(), T_final.data_ptr<float>(),
        last_ids.data_ptr<int32_t>(), v_render_colors.data_ptr<float>(), v_render_alphas.data_ptr<float>(),
        v_means2d.data_ptr<float>(), v_conics.data_ptr<float>(), v_colors.data_ptr<float>(),
        v_opacities.data_ptr<float>(), isect_ptr, thread_ptr, nt
    );
    return {v_means2d, v_conics, v_colors, v_opacities};
}

namespace {

// ---------------------------------------------------------------------------
// Tile intersection (gsplat isect_tiles + isect_offset_encode, non-packed).
// Order: camera, tile, depth, ties in depth by flattened Gaussian index
// (gsplat's radix sort is stable and emits intersections in Gaussian order).
// Returns (isect_offsets [C, tiles_y, tiles_x] int32, flatten_ids [n_isects] int32,
//          tiles_per_gauss [C, N] int32).
// ---------------------------------------------------------------------------
// Tile rectangle [x0, x1) x [y0, y1) of each Gaussian, as gsplat computes it (float division, floor /
// ceil, clamp to the grid; empty for radius 0), and its tile count.  Branch free, so GCC vectorises it.
// One record per Gaussian, read together when the lists are filled (in depth order: random access).
struct TileRect {
    int32_t x0, y0, x1, y1;
    int64_t band;  // first of its narrowed tile rows (Bands), or -1: every tile of the rectangle
};
using TileRects = std::vector<TileRect>;

TileRects tile_rects(
    int64_t CN, const float *m, const int32_t *r, float tsf, int64_t tile_width, int64_t tile_height,
    int32_t *tpg, int nt
) {
    TileRects rc((size_t)CN);
    const vf tw = vset((float)tile_width), th = vset((float)tile_height), zero = vset(0.f);
    // clamp to [0, hi] with NaN -> 0, then truncate (the values are integral already)
    auto clampi = [&](vf v, vf hi) -> vi {
        const vf lo = vsel(V_GT(v, zero), v, zero);
        return __builtin_convertvector(vsel(V_GE(lo, hi), hi, lo), vi);
    };
    const int64_t n_blocks = (CN + VW - 1) / VW;
#pragma omp parallel for schedule(static) num_threads(nt)
    for (int64_t blk = 0; blk < n_blocks; ++blk) {
        const int64_t i0 = blk * VW;
        const int L = (int)std::min<int64_t>(VW, CN - i0);
        vf rad, mx, my;
        for (int l = 0; l < VW; ++l) {
            const int64_t i = i0 + (l < L ? l : 0);
            rad[l] = (float)r[i];
            mx[l] = m[2 * i];
            my[l] = m[2 * i + 1];
        }
        const vi live = V_GT(rad, zero);  // radius 0: no tiles
        const vf tr = rad / tsf, tx = mx / tsf, ty = my / tsf;
        const vi a = clampi(vfloor(tx - tr), tw) & live, b = clampi(vfloor(ty - tr), th) & live;
        const vi c = clampi(vceil(tx + tr), tw) & live, d = clampi(vceil(ty + tr), th) & live;
        const vi n = (d - b) * (c - a);
        for (int l = 0; l < L; ++l) {
            rc[i0 + l] = TileRect{a[l], b[l], c[l], d[l], -1};
            tpg[i0 + l] = n[l];
        }
    }
    return rc;
}

// The tiles of each Gaussian's rectangle that its footprint reaches (Speedy-Splat's AccuTile, with the
// rasterizer's own footprint): for each tile row of the rectangle, the hull [bx0, bx1) of the tile
// columns whose pixels some row span of :func:`prep_spans` reaches (the spans the rasterizer visits, in
// global columns).  A pair outside it would visit no pixel in the forward or the backward, so leaving
// it out of the lists changes no image and no gradient.  A Gaussian of opacity < 1/255 (kSkip: alpha <
// 1/255 everywhere) has no pairs; one of fewer than kFootprintMinTiles tiles keeps them (its footprint
// is not worth computing); one whose footprint cannot be bounded (kFull) keeps its rectangle.  A narrowed
// Gaussian's tile rows are bands x0/x1[rc[i].band + row] (one per row of its rectangle);
// tiles_per_gauss and the rectangles are updated to the pairs kept.
struct Bands {
    std::vector<int32_t> x0, x1;
};
// Rectangles of fewer tiles keep them: a footprint costs about what the pair visits it saves (bench
// train, orbit and a 1-MP scene; tiles.py: FOOTPRINT_MIN_TILES).
constexpr int32_t kFootprintMinTiles = STEALTH_NS_FOOTPRINT_MIN_TILES;

Bands footprint_bands(
    int64_t CN, const float *m, const float *con, const float *opa, int W, int H, int ts, TileRects &rc,
    int32_t *tpg, int nt
) {
    Bands bd;
    std::vector<int64_t> off((size_t)CN + 1, 0);  // off[i]: Gaussian i's first band
    for (int64_t i = 0; i < CN; ++i) {
        if (tpg[i] > 0 && opa[i] < kAlphaMin) {  // make_prep's kSkip
            tpg[i] = 0;
            rc[i].x1 = rc[i].x0;
            rc[i].y1 = rc[i].y0;
        }
        off[i + 1] = off[i] + (tpg[i] >= kFootprintMinTiles ? rc[i].y1 - rc[i].y0 : 0);
    }
    if (off[CN] == 0) return bd;  // nothing to narrow: the rectangles as they are
    bd.x0.resize((size_t)off[CN]);
    bd.x1.resize((size_t)off[CN]);
#pragma omp parallel num_threads(nt)
    {
        std::vector<int32_t> lo((size_t)(ts + VW)), hi((size_t)(ts + VW));
#pragma omp for schedule(dynamic, 256)
        for (int64_t i = 0; i < CN; ++i) {
            if (off[i + 1] == off[i]) continue;
            const GPrep p = make_prep(m + 2 * i, con + 3 * i, opa[i], (float)(W + H), true);
            rc[i].band = off[i];
            const int32_t rx0 = rc[i].x0, rx1 = rc[i].x1;
            int32_t n = 0;
            for (int32_t ty = rc[i].y0; ty < rc[i].y1; ++ty) {
                const int y_base = ty * ts, ty1 = std::min(y_base + ts, H);
                int32_t bx0 = rx0, bx1 = rx1;  // kFull: the whole row of the rectangle
                if (p.kind == kEllipse) {
                    bx0 = rx1;
                    bx1 = rx0;
                    if (ty1 > y_base) {
                        int r0, r1;
                        prep_spans(p, 0, W, y_base, ty1, r0, r1, lo.data(), hi.data());
                        int32_t first = W, last = 0;  // hull of the row spans, in pixels
                        for (int r = r0 - y_base; r < r1 - y_base; ++r) {
                            const bool some = hi[r] > lo[r];
                            first = some && lo[r] < first ? lo[r] : first;
                            last = some && hi[r] > last ? hi[r] : last;
                        }
                        if (last > first) {  // one division each, not two per row
                            bx0 = first / ts;
                            bx1 = (last - 1) / ts + 1;
                        }
                    }
                    bx0 = std::max(bx0, rx0);
                    bx1 = std::min(bx1, rx1);
                    if (bx1 < bx0) bx1 = bx0;
                }
                const int64_t k = off[i] + (ty - rc[i].y0);
                bd.x0[k] = bx0;
                bd.x1[k] = bx1;
                n += bx1 - bx0;
            }
            tpg[i] = n;
        }
    }
    return bd;
}

// Per camera, the Gaussians with tiles in (depth, index) order: stable LSD radix sort (4 x 8 bits) of
// an order-preserving uint32 image of the float depth.  For positive depths (the only ones with
// radii > 0 when near_plane > 0) this is gsplat's order (its key is the float's bit pattern); for
// negative depths gsplat's key is ill-defined and we simply use the float order.  order[c * N + s] is
// the s-th Gaussian of camera c, for s < n_live[c].
std::vector<int32_t> depth_order(
    int64_t C, int64_t N, const int32_t *tpg, const float *dep, std::vector<int64_t> &n_live_out, int nt
) {
    std::vector<int32_t> order((size_t)(C * N), -1);
    n_live_out.assign((size_t)C, 0);
#pragma omp parallel num_threads(nt)
    {
        std::vector<uint32_t> key_a, key_b;
        std::vector<int32_t> id_b;
#pragma omp for schedule(dynamic, 1)
        for (int64_t c = 0; c < C; ++c) {
            int32_t *o = order.data() + c * N;
            int64_t n_live = 0;
            key_a.clear();
            for (int64_t i = 0; i < N; ++i) {
                if (tpg[c * N + i] <= 0) continue;
                float d = dep[c * N + i];
                if (d == 0.f) d = 0.f;  // -0 == +0
                uint32_t kbits;
                std::memcpy(&kbits, &d, 4);
                // order-preserving map float -> uint32 (negative: flip all bits, else flip sign)
                key_a.push_back((kbits & 0x80000000u) ? ~kbits : (kbits ^ 0x80000000u));
                o[n_live++] = (int32_t)i;
            }
            n_live_out[c] = n_live;
            if (n_live == 0) continue;
            key_b.resize(n_live);
            id_b.resize(n_live);
            uint32_t *ka = key_a.data(), *kb = key_b.data();
            int32_t *ia = o, *ib = id_b.data();
            for (int shift = 0; shift < 32; shift += 8) {
                int64_t hist[257] = {0};
                for (int64_t i = 0; i < n_live; ++i) hist[((ka[i] >> shift) & 0xFF) + 1] += 1;
                if (hist[((ka[0] >> shift) & 0xFF) + 1] == n_live) continue;  // all in one bucket
                for (int r = 0; r < 256; ++r) hist[r + 1] += hist[r];
                for (int64_t i = 0; i < n_live; ++i) {
                    const int64_t dst = hist[(ka[i] >> shift) & 0xFF]++;
                    kb[dst] = ka[i];
                    ib[dst] = ia[i];
                }
                std::swap(ka, kb);
                std::swap(ia, ib);
            }
            if (ia != o) std::memcpy(o, ia, sizeof(int32_t) * n_live);
        }
    }
    return order;
}

// How many Gaussians ahead the binning fetches a rectangle (a cache miss each, in depth order).
constexpr int64_t kBinPrefetch = 16;

// The tile lists (offsets [C, tiles_y, tiles_x], flatten_ids) from the depth order: a parallel
// counting sort.  Thread t takes the t-th chunk of each camera's depth order, counts its pairs per
// tile, and after a prefix sum writes them from its own cursor, which lies after the cursors of
// threads t' < t: every list stays in depth order, the same for any thread count.
std::vector<at::Tensor> bin_by_tile(
    int64_t C, int64_t N, int64_t tile_width, int64_t tile_height, const TileRects &rc, const Bands &bd,
    const int32_t *order, const std::vector<int64_t> &n_live, const at::TensorOptions &iopt, int nt
) {
    const int64_t n_tiles = tile_width * tile_height, n_bins = C * n_tiles;
    auto offsets = at::empty({C, tile_height, tile_width}, iopt);
    int32_t *off = offsets.data_ptr<int32_t>();
    at::Tensor flatten_ids;
    std::vector<int64_t> cursors((size_t)(nt * n_bins), 0);  // per thread: counts, then cursors
    bool overflow = false;
    const TileRect *__restrict__ rects = rc.data();
    const int32_t *__restrict__ bx0s = bd.x0.data(), *__restrict__ bx1s = bd.x1.data();
#pragma omp parallel num_threads(nt)
    {
        const int t = omp_get_thread_num(), T = omp_get_num_threads();
        int64_t *__restrict__ cur = cursors.data() + t * n_bins;
        // on_pair(bin, Gaussian) for every pair of this thread's chunks, in depth order
        auto visit_pairs = [&](auto &&on_pair) {
            for (int64_t c = 0; c < C; ++c) {
                const int32_t *__restrict__ o = order + c * N;
                const int64_t s0 = n_live[c] * t / T, s1 = n_live[c] * (t + 1) / T;
                for (int64_t s = s0; s < s1; ++s) {
                    // depth order visits the rectangles at random: fetch ahead, the bands once the
                    // rectangle has arrived
                    if (s + kBinPrefetch < s1) __builtin_prefetch(rects + c * N + o[s + kBinPrefetch]);
                    if (s + kBinPrefetch / 2 < s1) {
                        const int64_t band = rects[c * N + o[s + kBinPrefetch / 2]].band;
                        if (band >= 0) {
                            __builtin_prefetch(bx0s + band);
                            __builtin_prefetch(bx1s + band);
                        }
                    }
                    const int64_t gi = c * N + o[s];
                    const TileRect r = rects[gi];
                    for (int32_t y = r.y0; y < r.y1; ++y) {
                        const int64_t row = c * n_tiles + (int64_t)y * tile_width;
                        const int64_t k = r.band + (y - r.y0);
                        const int32_t x0 = r.band >= 0 ? bx0s[k] : r.x0, x1 = r.band >= 0 ? bx1s[k] : r.x1;
                        for (int32_t x = x0; x < x1; ++x) on_pair(row + x, (int32_t)gi);
                    }
                }
            }
        };
        visit_pairs([&](int64_t bin, int32_t) { cur[bin] += 1; });
#pragma omp barrier
#pragma omp single
        {
            int64_t total = 0;
            for (int64_t b = 0; b < n_bins; ++b) {
                overflow |= total > (int64_t)std::numeric_limits<int32_t>::max();
                off[b] = (int32_t)total;
                for (int u = 0; u < T; ++u) {
                    const int64_t n = cursors[u * n_bins + b];
                    cursors[u * n_bins + b] = total;
                    total += n;
                }
            }
            overflow |= total > (int64_t)std::numeric_limits<int32_t>::max();
            flatten_ids = at::empty({overflow ? 0 : total}, iopt);
        }  // implicit barrier
        if (!overflow) {
            int32_t *__restrict__ fid = flatten_ids.data_ptr<int32_t>();
            visit_pairs([&](int64_t bin, int32_t gi) { fid[cur[bin]++] = gi; });
        }
    }
    TORCH_CHECK(!overflow, "too many intersections");
    return {offsets, flatten_ids};
}

}  // namespace

std::vector<at::Tensor> isect_tiles(
    const at::Tensor &means2d, const at::Tensor &radii, const at::Tensor &depths, int64_t tile_size,
    int64_t tile_width, int64_t tile_height, int64_t n_threads, const at::Tensor &conics,
    const at::Tensor &opacities, int64_t image_width, int64_t image_height
) {
    check_cpu_f32(means2d, "means2d");
    check_cpu_i32(radii, "radii");
    check_cpu_f32(depths, "depths");
    TORCH_CHECK(means2d.dim() == 3 && means2d.size(2) == 2, "means2d must be [C, N, 2]");
    const int64_t C = means2d.size(0), N = means2d.size(1);
    TORCH_CHECK(radii.numel() == C * N && depths.numel() == C * N, "radii/depths must be [C, N]");
    TORCH_CHECK(tile_size >= 1 && tile_width >= 0 && tile_height >= 0, "bad tile grid");
    const int64_t n_tiles = tile_width * tile_height;
    TORCH_CHECK(n_tiles < (int64_t)std::numeric_limits<int32_t>::max(), "too many tiles");
    const int nt = resolve_threads(n_threads);
    auto iopt = means2d.options().dtype(at::kInt);
    auto tiles_per_gauss = at::empty({C, N}, iopt);
    int32_t *tpg = tiles_per_gauss.data_ptr<int32_t>();
    TileRects rc = tile_rects(
        C * N, means2d.data_ptr<float>(), radii.data_ptr<int32_t>(), (float)tile_size, tile_width, tile_height,
        tpg, nt
    );
    Bands bd;  // empty: every pair of the rectangles (gsplat's lists)
    if (conics.defined() && conics.numel() > 0) {
        check_cpu_f32(conics, "conics");
        check_cpu_f32(opacities, "opacities");
        TORCH_CHECK(conics.numel() == C * N * 3 && opacities.numel() == C * N, "conics/opacities must be [C, N, 3]/[C, N]");
        TORCH_CHECK(image_width > 0 && image_height > 0, "the footprint needs the image size");
        TORCH_CHECK(tile_width * tile_size >= image_width && tile_height * tile_size >= image_height, "tile grid smaller than the image");
        bd = footprint_bands(
            C * N, means2d.data_ptr<float>(), conics.data_ptr<float>(), opacities.data_ptr<float>(),
            (int)image_width, (int)image_height, (int)tile_size, rc, tpg, nt
        );
    }
    std::vector<int64_t> n_live;
    const std::vector<int32_t> order = depth_order(C, N, tpg, depths.data_ptr<float>(), n_live, nt);
    std::vector<at::Tensor> lists =
        bin_by_tile(C, N, tile_width, tile_height, rc, bd, order.data(), n_live, iopt, nt);
    const at::Tensor &offsets = lists[0], &flatten_ids = lists[1];
    return {offsets, flatten_ids, tiles_per_gauss};
}

}  // namespace stealth_ns
