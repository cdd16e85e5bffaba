// The EWA projection of 3D Gaussians, fused: forward (with the pixel boxes) and backward, and
// the front-to-back order of the drawn Gaussians. prosplat/render/projection.py is its twin.
//
// Per Gaussian, in double precision: camera-space mean, pixel mean, the 2D conic of
// M Mᵀ + 0.3 I with M = J·R_cam·R_q·diag(s) (J at x/z, y/z clamped to 1.3x the field of
// view), z, and the inclusive pixel box outside which alpha < 1/255. The backward pass
// recomputes the forward per Gaussian and walks it back by hand. cam = R (9, row-major), t (3),
// fx, fy, cx, cy, x/z low, x/z high, y/z low, y/z high, near, dilation. Compiled into the same
// library as _cpu_kernels.cpp (prosplat/render/native.py).

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

#include "_cpu_parallel.h"

namespace {

using prosplat_cpu::parallel_chunks;

// torch.clamp(x, lo, hi): NaN stays NaN.
inline double clamp_nan(double x, double lo, double hi) {
  return std::isnan(x) ? x : std::min(std::max(x, lo), hi);
}

// The view's size and the widest standard deviation drawn (px; <= 0: no limit).
struct Frame {
  double W, H, limit;
  explicit Frame(const double* f) : W(f[0]), H(f[1]), limit(f[2]) {}
};

struct ProjCam {
  double R[9], t[3], fx, fy, cx, cy, lox, hix, loy, hiy, near, dil;
  explicit ProjCam(const double* c) {
    for (int i = 0; i < 9; ++i) R[i] = c[i];
    for (int i = 0; i < 3; ++i) t[i] = c[9 + i];
    fx = c[12]; fy = c[13]; cx = c[14]; cy = c[15];
    lox = c[16]; hix = c[17]; loy = c[18]; hiy = c[19]; near = c[20]; dil = c[21];
  }
};

struct ProjState {
  double x, y, z, inv_z, xz, yz, xzc, yzc, ux, uy;
  bool front, inx, iny;
  double qn[4], qlen, rq[3][3], v0[3], v1[3], P0[3], P1[3], r0[3], r1[3], s[3];
  double a0, c0, b, k[3], det;
};

inline void proj_state(const ProjCam& c, const double* m, const double* q, const double* sc,
                       ProjState& st) {
  st.x = c.R[0] * m[0] + c.R[1] * m[1] + c.R[2] * m[2] + c.t[0];
  st.y = c.R[3] * m[0] + c.R[4] * m[1] + c.R[5] * m[2] + c.t[1];
  st.z = c.R[6] * m[0] + c.R[7] * m[1] + c.R[8] * m[2] + c.t[2];
  st.front = st.z >= c.near;
  st.inv_z = 1.0 / (st.front ? st.z : 1.0);
  st.xz = st.x * st.inv_z;
  st.yz = st.y * st.inv_z;
  st.inx = st.xz >= c.lox && st.xz <= c.hix;
  st.iny = st.yz >= c.loy && st.yz <= c.hiy;
  st.xzc = std::min(std::max(st.xz, c.lox), c.hix);
  st.yzc = std::min(std::max(st.yz, c.loy), c.hiy);
  st.ux = c.fx * st.inv_z;
  st.uy = c.fy * st.inv_z;
  for (int k = 0; k < 3; ++k) {
    st.v0[k] = st.ux * (c.R[k] - st.xzc * c.R[6 + k]);
    st.v1[k] = st.uy * (c.R[3 + k] - st.yzc * c.R[6 + k]);
  }
  st.qlen = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  for (int i = 0; i < 4; ++i) st.qn[i] = q[i] / st.qlen;
  const double w = st.qn[0], x = st.qn[1], y = st.qn[2], z = st.qn[3];
  st.rq[0][0] = 1 - 2 * (y * y + z * z); st.rq[0][1] = 2 * (x * y - w * z); st.rq[0][2] = 2 * (x * z + w * y);
  st.rq[1][0] = 2 * (x * y + w * z); st.rq[1][1] = 1 - 2 * (x * x + z * z); st.rq[1][2] = 2 * (y * z - w * x);
  st.rq[2][0] = 2 * (x * z - w * y); st.rq[2][1] = 2 * (y * z + w * x); st.rq[2][2] = 1 - 2 * (x * x + y * y);
  for (int j = 0; j < 3; ++j) {
    st.s[j] = sc[j];
    st.P0[j] = st.v0[0] * st.rq[0][j] + st.v0[1] * st.rq[1][j] + st.v0[2] * st.rq[2][j];
    st.P1[j] = st.v1[0] * st.rq[0][j] + st.v1[1] * st.rq[1][j] + st.v1[2] * st.rq[2][j];
    st.r0[j] = st.P0[j] * st.s[j];
    st.r1[j] = st.P1[j] * st.s[j];
  }
  st.a0 = st.r0[0] * st.r0[0] + st.r0[1] * st.r0[1] + st.r0[2] * st.r0[2];
  st.c0 = st.r1[0] * st.r1[0] + st.r1[1] * st.r1[1] + st.r1[2] * st.r1[2];
  st.b = st.r0[0] * st.r1[0] + st.r0[1] * st.r1[1] + st.r0[2] * st.r1[2];
  st.k[0] = st.r0[1] * st.r1[2] - st.r0[2] * st.r1[1];
  st.k[1] = st.r0[2] * st.r1[0] - st.r0[0] * st.r1[2];
  st.k[2] = st.r0[0] * st.r1[1] - st.r0[1] * st.r1[0];
  st.det = st.k[0] * st.k[0] + st.k[1] * st.k[1] + st.k[2] * st.k[2] + c.dil * (st.a0 + st.c0) +
           c.dil * c.dil;
}

// The inclusive pixel box (x0, x1, y0, y1) and drawn flag of a Gaussian at pixel (u, v)
// with dilated covariance diagonal a, c: prosplat.render.projection.pixel_boxes, the same
// IEEE double operations in the same order (ceil, floor, clamp and sqrt are exact, and r2,
// whose log torch and libm round differently, comes in from torch).
inline bool pixel_box(double u, double v, double a, double c, double o, double r2, bool front,
                      const Frame& f, int32_t* box) {
  const double half_w = std::sqrt(r2 * a) * (1 + 1e-4) + 1e-3;
  const double half_h = std::sqrt(r2 * c) * (1 + 1e-4) + 1e-3;
  const double x0 = clamp_nan(std::ceil(u - half_w - 0.5), 0.0, f.W);
  const double x1 = clamp_nan(std::floor(u + half_w - 0.5), -1.0, f.W - 1);
  const double y0 = clamp_nan(std::ceil(v - half_h - 0.5), 0.0, f.H);
  const double y1 = clamp_nan(std::floor(v + half_h - 0.5), -1.0, f.H - 1);
  const bool ok = front && o >= 1.0 / 255.0 && x0 <= x1 && y0 <= y1 && std::isfinite(half_w) &&
                  std::isfinite(half_h);
  if (ok) {
    box[0] = int32_t(x0); box[1] = int32_t(x1); box[2] = int32_t(y0); box[3] = int32_t(y1);
  } else {
    box[0] = 1; box[1] = 0; box[2] = 1; box[3] = 0;
  }
  return ok;
}

// prosplat.render.projection.wider_than on the conic as the caller sees it (rounded to TO):
// its widest standard deviation above `limit` px.
template <typename TO>
inline bool wider(const TO* conic, double limit) {
  const double a = double(conic[0]), b = double(conic[1]), c = double(conic[2]);
  const double h = (a - c) / 2;
  const double low = (a + c) / 2 - std::sqrt(h * h + b * b);
  return low * limit * limit < 1;
}

// Forward pass: reads TI (float or double) inputs, works in double, writes TO outputs (a
// double -> float cast rounds as torch's .to does), so the no-grad path needs no float64
// copies of the Gaussians. Also the pixel boxes and the drawn flag, with the Gaussians wider
// than frame.limit (> 0) not drawn.
template <typename TI, typename TO>
void project_forward(int64_t n, const TI* means, const TI* quats, const TI* scales,
                     const double* cam, const double* opac, const double* r2, const double* frame,
                     TO* means2d, TO* conics, TO* depth, int32_t* boxes, uint8_t* valid,
                     int n_threads) {
  const ProjCam c(cam);
  const Frame f(frame);
  parallel_chunks(n, 4096, n_threads, [&](int64_t g) {
    ProjState st;
    double m[3], q[4], sc[3];
    for (int i = 0; i < 3; ++i) m[i] = double(means[3 * g + i]), sc[i] = double(scales[3 * g + i]);
    for (int i = 0; i < 4; ++i) q[i] = double(quats[4 * g + i]);
    proj_state(c, m, q, sc, st);
    const double u = c.fx * st.xz + c.cx, v = c.fy * st.yz + c.cy;
    means2d[2 * g] = TO(u);
    means2d[2 * g + 1] = TO(v);
    const double a = st.a0 + c.dil, cc = st.c0 + c.dil, inv_det = 1.0 / st.det;
    TO* con = conics + 3 * g;
    con[0] = TO(cc * inv_det);
    con[1] = TO(-st.b * inv_det);
    con[2] = TO(a * inv_det);
    depth[g] = TO(st.z);
    bool ok = pixel_box(u, v, a, cc, opac[g], r2[g], st.front, f, boxes + 4 * g);
    if (ok && f.limit > 0 && wider(con, f.limit)) ok = false;
    valid[g] = ok ? 1 : 0;
  });
}

void project_backward(int64_t n, const double* means, const double* quats, const double* scales,
                      const double* cam, const double* g_m2d, const double* g_con,
                      const double* g_depth, double* g_means, double* g_quats, double* g_scales,
                      int n_threads) {
  const ProjCam c(cam);
  parallel_chunks(n, 4096, n_threads, [&](int64_t g) {
    ProjState st;
    proj_state(c, means + 3 * g, quats + 4 * g, scales + 3 * g, st);
    const double a = st.a0 + c.dil, cc = st.c0 + c.dil, inv_det = 1.0 / st.det;
    const double gA = g_con[3 * g], gB = g_con[3 * g + 1], gC = g_con[3 * g + 2];
    // conic = (c, -b, a) / det
    const double g_det = -(gA * cc - gB * st.b + gC * a) * inv_det * inv_det;
    const double g_a0 = gC * inv_det + c.dil * g_det;
    const double g_c0 = gA * inv_det + c.dil * g_det;
    const double g_b = -gB * inv_det;
    double gk[3];
    for (int i = 0; i < 3; ++i) gk[i] = 2 * st.k[i] * g_det;
    double gr0[3], gr1[3];
    for (int j = 0; j < 3; ++j) {
      gr0[j] = 2 * st.r0[j] * g_a0 + st.r1[j] * g_b;
      gr1[j] = 2 * st.r1[j] * g_c0 + st.r0[j] * g_b;
    }
    // k0 = r0_1 r1_2 - r0_2 r1_1; k1 = r0_2 r1_0 - r0_0 r1_2; k2 = r0_0 r1_1 - r0_1 r1_0
    gr0[1] += gk[0] * st.r1[2]; gr1[2] += gk[0] * st.r0[1];
    gr0[2] -= gk[0] * st.r1[1]; gr1[1] -= gk[0] * st.r0[2];
    gr0[2] += gk[1] * st.r1[0]; gr1[0] += gk[1] * st.r0[2];
    gr0[0] -= gk[1] * st.r1[2]; gr1[2] -= gk[1] * st.r0[0];
    gr0[0] += gk[2] * st.r1[1]; gr1[1] += gk[2] * st.r0[0];
    gr0[1] -= gk[2] * st.r1[0]; gr1[0] -= gk[2] * st.r0[1];
    double gv0[3] = {0, 0, 0}, gv1[3] = {0, 0, 0}, grq[3][3];
    for (int j = 0; j < 3; ++j) {
      g_scales[3 * g + j] = gr0[j] * st.P0[j] + gr1[j] * st.P1[j];
      const double gP0 = gr0[j] * st.s[j], gP1 = gr1[j] * st.s[j];
      for (int i = 0; i < 3; ++i) {
        gv0[i] += gP0 * st.rq[i][j];
        gv1[i] += gP1 * st.rq[i][j];
        grq[i][j] = gP0 * st.v0[i] + gP1 * st.v1[i];
      }
    }
    // v0_k = ux (R0k - xzc R2k), v1_k = uy (R1k - yzc R2k)
    double g_ux = 0, g_uy = 0, g_xzc = 0, g_yzc = 0;
    for (int k = 0; k < 3; ++k) {
      g_ux += gv0[k] * (c.R[k] - st.xzc * c.R[6 + k]);
      g_uy += gv1[k] * (c.R[3 + k] - st.yzc * c.R[6 + k]);
      g_xzc -= gv0[k] * st.ux * c.R[6 + k];
      g_yzc -= gv1[k] * st.uy * c.R[6 + k];
    }
    double g_xz = c.fx * g_m2d[2 * g] + (st.inx ? g_xzc : 0.0);
    double g_yz = c.fy * g_m2d[2 * g + 1] + (st.iny ? g_yzc : 0.0);
    double g_inv_z = c.fx * g_ux + c.fy * g_uy + g_xz * st.x + g_yz * st.y;
    const double gx = g_xz * st.inv_z, gy = g_yz * st.inv_z;
    double gz = g_depth[g] + (st.front ? -g_inv_z * st.inv_z * st.inv_z : 0.0);
    for (int i = 0; i < 3; ++i)
      g_means[3 * g + i] = c.R[i] * gx + c.R[3 + i] * gy + c.R[6 + i] * gz;
    // rotation entries -> normalised quaternion -> quaternion
    const double w = st.qn[0], x = st.qn[1], y = st.qn[2], z = st.qn[3];
    const double (*G)[3] = grq;
    double gq[4];
    gq[0] = 2 * (-z * G[0][1] + y * G[0][2] + z * G[1][0] - x * G[1][2] - y * G[2][0] + x * G[2][1]);
    gq[1] = 2 * (y * G[0][1] + z * G[0][2] + y * G[1][0] - 2 * x * G[1][1] - w * G[1][2] +
                 z * G[2][0] + w * G[2][1] - 2 * x * G[2][2]);
    gq[2] = 2 * (-2 * y * G[0][0] + x * G[0][1] + w * G[0][2] + x * G[1][0] + z * G[1][2] -
                 w * G[2][0] + z * G[2][1] - 2 * y * G[2][2]);
    gq[3] = 2 * (-2 * z * G[0][0] - w * G[0][1] + x * G[0][2] + w * G[1][0] - 2 * z * G[1][1] +
                 y * G[1][2] + x * G[2][0] + y * G[2][1]);
    const double dot = gq[0] * w + gq[1] * x + gq[2] * y + gq[3] * z;
    for (int i = 0; i < 4; ++i) g_quats[4 * g + i] = (gq[i] - st.qn[i] * dot) / st.qlen;
  });
}

// A float's bits as an unsigned key in the float's order (-0 before +0; no NaN comes here).
inline uint32_t order_key(float x) {
  uint32_t b;
  std::memcpy(&b, &x, 4);
  return (b & 0x80000000u) ? ~b : (b | 0x80000000u);
}
inline uint64_t order_key(double x) {
  uint64_t b;
  std::memcpy(&b, &x, 8);
  return (b & 0x8000000000000000ull) ? ~b : (b | 0x8000000000000000ull);
}

// The indices g with valid[g], sorted by depth[g] and, among equal depths, by g: what
// torch.argsort(depth[idx], stable=True) gives over idx = nonzero(valid), for the depths of
// drawn Gaussians (>= the near plane > 0, so never NaN or -0). An LSD radix sort of 11-bit
// digits, stable by construction; the passes where every key shares the digit are skipped.
// Returns how many were written to order.
template <typename T>
int64_t depth_order(int64_t n, const T* depth, const uint8_t* valid, int64_t* order) {
  using K = decltype(order_key(T(0)));
  constexpr int kBits = 11, kBuckets = 1 << kBits, kKeyBits = int(sizeof(K)) * 8;
  constexpr int kPasses = (kKeyBits + kBits - 1) / kBits;
  std::vector<K> keys, keys2;
  keys.reserve(size_t(n));
  int64_t m = 0;
  for (int64_t g = 0; g < n; ++g)
    if (valid[g]) {
      keys.push_back(order_key(depth[g]));
      order[m++] = g;
    }
  std::vector<int64_t> counts(size_t(kPasses) * kBuckets, 0);
  for (int64_t i = 0; i < m; ++i)
    for (int p = 0; p < kPasses; ++p)
      counts[size_t(p) * kBuckets + ((keys[i] >> (p * kBits)) & (kBuckets - 1))]++;
  keys2.resize(static_cast<size_t>(m));
  std::vector<int64_t> idx2(static_cast<size_t>(m));
  int64_t* src_i = order;
  int64_t* dst_i = idx2.data();
  K* src_k = keys.data();
  K* dst_k = keys2.data();
  for (int p = 0; p < kPasses; ++p) {
    int64_t* cnt = counts.data() + size_t(p) * kBuckets;
    if (std::any_of(cnt, cnt + kBuckets, [m](int64_t c) { return c == m; })) continue;
    int64_t sum = 0;
    for (int b = 0; b < kBuckets; ++b) {
      const int64_t c = cnt[b];
      cnt[b] = sum;
      sum += c;
    }
    for (int64_t i = 0; i < m; ++i) {
      const int64_t at = cnt[(src_k[i] >> (p * kBits)) & (kBuckets - 1)]++;
      dst_k[at] = src_k[i];
      dst_i[at] = src_i[i];
    }
    std::swap(src_k, dst_k);
    std::swap(src_i, dst_i);
  }
  if (src_i != order) std::copy(src_i, src_i + m, order);
  return m;
}

}  // namespace

#define PROSPLAT_EXPORT extern "C" __attribute__((visibility("default")))

#define PROSPLAT_DEFINE_PROJECT(T, SUFFIX)                                                         \
  PROSPLAT_EXPORT void prosplat_project_forward_##SUFFIX(                                          \
      int64_t n, const T* means, const T* quats, const T* scales, const double* cam,             \
      const double* opac, const double* r2, const double* frame, T* means2d, T* conics,           \
      T* depth, int32_t* boxes, uint8_t* valid, int n_threads) {                                  \
    project_forward<T, T>(n, means, quats, scales, cam, opac, r2, frame, means2d, conics, depth, \
                          boxes, valid, n_threads);                                               \
  }                                                                                               \
  PROSPLAT_EXPORT int64_t prosplat_depth_order_##SUFFIX(int64_t n, const T* depth,                 \
                                                         const uint8_t* valid, int64_t* order) {  \
    return depth_order<T>(n, depth, valid, order);                                                \
  }

PROSPLAT_DEFINE_PROJECT(float, f32)
PROSPLAT_DEFINE_PROJECT(double, f64)

PROSPLAT_EXPORT void prosplat_project_backward_f64(
    int64_t n, const double* means, const double* quats, const double* scales, const double* cam,
    const double* g_m2d, const double* g_con, const double* g_depth, double* g_means,
    double* g_quats, double* g_scales, int n_threads) {
  project_backward(n, means, quats, scales, cam, g_m2d, g_con, g_depth, g_means, g_quats,
                   g_scales, n_threads);
}
