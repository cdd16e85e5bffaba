// Tile-based alpha compositing of projected 2D Gaussians on the CPU: forward and backward.
//
// Projection (EWA, SH colour) happens in torch so autograd covers it; this file only does
// the part torch cannot do fast: per-pixel front-to-back compositing with early termination.
// Plain C ABI (no torch headers) so it compiles in about a second with any C++17 compiler
// and is loaded with ctypes. Threads are std::thread over tiles (no OpenMP runtime to clash
// with torch's).
//
// Semantics (must match prosplat/render/reference.py exactly):
//   pixel (x, y) centre is (x + 0.5, y + 0.5); d = centre - mean2d
//   alpha = min(0.99, o * exp(-0.5 * d^T Conic d)); alpha < 1/255 -> sample skipped
//   a pixel stops before the sample that would take its transmittance below 1e-4
//   out[f] = sum_i w_i feat_i[f], w_i = alpha_i * T_i; T_final returned separately.
// Each Gaussian carries an inclusive pixel box outside which alpha < 1/255 is guaranteed
// (computed in Python from an opacity-aware radius), so culling never changes the image.

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <thread>
#include <vector>

namespace {

constexpr int kTile = 16;

struct TileLists {
  int tiles_x = 0, tiles_y = 0;
  std::vector<int64_t> offsets;  // [tiles + 1]
  std::vector<int64_t> ids;      // gaussian indices, depth-sorted within each tile
};

// Bin the depth-sorted Gaussians into 16x16 tiles. Sequential and in depth order, so each
// tile's list comes out already sorted without a per-tile sort.
TileLists build_tile_lists(int64_t n_sorted, const int64_t* order, const int32_t* boxes, int width,
                           int height) {
  TileLists tl;
  tl.tiles_x = (width + kTile - 1) / kTile;
  tl.tiles_y = (height + kTile - 1) / kTile;
  const int64_t n_tiles = int64_t(tl.tiles_x) * tl.tiles_y;
  std::vector<int64_t> counts(n_tiles + 1, 0);
  for (int64_t k = 0; k < n_sorted; ++k) {
    const int32_t* b = boxes + 4 * order[k];
    if (b[0] > b[1] || b[2] > b[3]) continue;
    for (int ty = b[2] / kTile; ty <= b[3] / kTile; ++ty)
      for (int tx = b[0] / kTile; tx <= b[1] / kTile; ++tx) counts[int64_t(ty) * tl.tiles_x + tx]++;
  }
  tl.offsets.assign(n_tiles + 1, 0);
  for (int64_t t = 0; t < n_tiles; ++t) tl.offsets[t + 1] = tl.offsets[t] + counts[t];
  tl.ids.resize(tl.offsets[n_tiles]);
  std::vector<int64_t> cursor(tl.offsets.begin(), tl.offsets.end() - 1);
  for (int64_t k = 0; k < n_sorted; ++k) {
    const int64_t g = order[k];
    const int32_t* b = boxes + 4 * g;
    if (b[0] > b[1] || b[2] > b[3]) continue;
    for (int ty = b[2] / kTile; ty <= b[3] / kTile; ++ty)
      for (int tx = b[0] / kTile; tx <= b[1] / kTile; ++tx)
        tl.ids[cursor[int64_t(ty) * tl.tiles_x + tx]++] = g;
  }
  return tl;
}

// A tile's pixel rectangle (inclusive) and the index of a pixel within it.
struct TileRect {
  int x0, y0, x1, y1, w;
  int local(int x, int y) const { return (y - y0) * w + (x - x0); }
  int size() const { return w * (y1 - y0 + 1); }
};

TileRect tile_rect(const TileLists& tl, int64_t tile, int width, int height) {
  const int x0 = int(tile % tl.tiles_x) * kTile, y0 = int(tile / tl.tiles_x) * kTile;
  const int x1 = std::min(x0 + kTile, width) - 1, y1 = std::min(y0 + kTile, height) - 1;
  return {x0, y0, x1, y1, x1 - x0 + 1};
}

// The Gaussian's exponent at offset (dx, dy) from its mean. One function for both passes,
// so the backward pass skips and clamps exactly the samples the forward pass did.
template <typename T>
inline T gaussian_power(T dx, T dy, T ca, T cb, T cc) {
  return T(-0.5) * (ca * dx * dx + cc * dy * dy) - cb * dx * dy;
}

// Run worker(tid) for tid = 0..n_threads-1, worker 0 on the calling thread.
template <typename Worker>
void run_workers(int n_threads, Worker worker) {
  if (n_threads == 1) {
    worker(0);
    return;
  }
  std::vector<std::thread> pool;
  for (int i = 1; i < n_threads; ++i) pool.emplace_back(worker, i);
  worker(0);
  for (auto& th : pool) th.join();
}

template <typename Fn>
void parallel_tiles(int64_t n_tiles, int n_threads, Fn fn) {
  n_threads = std::max(1, std::min<int>(n_threads, int(n_tiles)));
  std::atomic<int64_t> next{0};
  run_workers(n_threads, [&](int tid) {
    for (int64_t t = next++; t < n_tiles; t = next++) fn(t, tid);
  });
}

// Thread tid takes tiles tid, tid + n, tid + 2n, ...: a fixed split, so each thread's
// gradient buffer sums the same tiles in the same order on every run (the backward pass is
// then bitwise reproducible for a thread count, which seeded refinement relies on).
template <typename Fn>
void parallel_tiles_static(int64_t n_tiles, int n_threads, Fn fn) {
  n_threads = std::max(1, std::min<int>(n_threads, int(n_tiles)));
  run_workers(n_threads, [&](int tid) {
    for (int64_t t = tid; t < n_tiles; t += n_threads) fn(t, tid);
  });
}

template <typename T>
void forward(int64_t n_sorted, int n_feat, int width, int height, const T* means2d, const T* conics,
             const T* opacities, const T* feats, const int32_t* boxes, const int64_t* order, T* out,
             T* out_trans, int32_t* out_last, int n_threads) {
  const TileLists tl = build_tile_lists(n_sorted, order, boxes, width, height);
  const int64_t n_pix = int64_t(width) * height;
  const T min_alpha = T(1) / T(255);
  parallel_tiles(int64_t(tl.tiles_x) * tl.tiles_y, n_threads, [&](int64_t tile, int) {
    const TileRect r = tile_rect(tl, tile, width, height);
    const int x0 = r.x0, y0 = r.y0, x1 = r.x1, y1 = r.y1;
    T trans[kTile * kTile];
    T acc[kTile * kTile * 8];
    std::vector<T> acc_big;  // only when n_feat > 8
    T* accp = acc;
    if (n_feat > 8) {
      acc_big.assign(size_t(kTile) * kTile * n_feat, T(0));
      accp = acc_big.data();
    } else {
      std::fill(acc, acc + kTile * kTile * n_feat, T(0));
    }
    int32_t last[kTile * kTile];
    bool done[kTile * kTile];
    const int n_local = r.size();
    std::fill(trans, trans + kTile * kTile, T(1));
    std::fill(last, last + kTile * kTile, 0);
    std::fill(done, done + kTile * kTile, false);
    int n_active = n_local;
    const int64_t begin = tl.offsets[tile], end = tl.offsets[tile + 1];
    for (int64_t k = begin; k < end && n_active > 0; ++k) {
      const int64_t g = tl.ids[k];
      const int32_t* b = boxes + 4 * g;
      const int bx0 = std::max<int>(b[0], x0), bx1 = std::min<int>(b[1], x1);
      const int by0 = std::max<int>(b[2], y0), by1 = std::min<int>(b[3], y1);
      const T mx = means2d[2 * g], my = means2d[2 * g + 1];
      const T ca = conics[3 * g], cb = conics[3 * g + 1], cc = conics[3 * g + 2];
      const T op = opacities[g];
      const T* fg = feats + int64_t(n_feat) * g;
      for (int y = by0; y <= by1; ++y) {
        const T dy = T(y) + T(0.5) - my;
        for (int x = bx0; x <= bx1; ++x) {
          const int p = r.local(x, y);
          if (done[p]) continue;
          const T dx = T(x) + T(0.5) - mx;
          const T power = gaussian_power(dx, dy, ca, cb, cc);
          const T alpha = std::min(T(0.99), op * std::exp(power));
          if (alpha < min_alpha) continue;
          const T next_t = trans[p] * (T(1) - alpha);
          if (next_t < T(1e-4)) {
            done[p] = true;
            --n_active;
            continue;
          }
          const T w = alpha * trans[p];
          T* ap = accp + p * n_feat;
          for (int f = 0; f < n_feat; ++f) ap[f] += w * fg[f];
          trans[p] = next_t;
          last[p] = int32_t(k - begin + 1);
        }
      }
    }
    for (int y = y0; y <= y1; ++y)
      for (int x = x0; x <= x1; ++x) {
        const int p = r.local(x, y);
        const int64_t pix = int64_t(y) * width + x;
        for (int f = 0; f < n_feat; ++f) out[f * n_pix + pix] = accp[p * n_feat + f];
        out_trans[pix] = trans[p];
        out_last[pix] = last[p];
      }
  });
}

// Reverse-mode pass. Walks each tile's list back to front, rebuilding T_i = T_{i+1}/(1-alpha_i)
// and the features composited behind each sample. Gradients go to per-thread buffers
// grads[tid, g, :] = (d mean2d x, y | d conic a, b, c | d opacity | d feat[0..F)).
template <typename T>
void backward(int64_t n_sorted, int n_feat, int width, int height, const T* means2d, const T* conics,
              const T* opacities, const T* feats, const int32_t* boxes, const int64_t* order,
              const T* trans_final, const int32_t* last, const T* grad_out, const T* grad_trans,
              T* grads, int64_t n_gauss, int n_threads) {
  const TileLists tl = build_tile_lists(n_sorted, order, boxes, width, height);
  const int64_t n_pix = int64_t(width) * height;
  const int stride = 6 + n_feat;
  const T min_alpha = T(1) / T(255);
  parallel_tiles_static(int64_t(tl.tiles_x) * tl.tiles_y, n_threads, [&](int64_t tile, int tid) {
    T* gbuf = grads + int64_t(tid) * n_gauss * stride;
    const TileRect r = tile_rect(tl, tile, width, height);
    const int x0 = r.x0, y0 = r.y0, x1 = r.x1, y1 = r.y1;
    const int n_local = r.size();
    std::vector<T> trans(n_local), t_final(n_local), g_t(n_local);
    std::vector<T> behind(size_t(n_local) * n_feat, T(0)), g_pix(size_t(n_local) * n_feat);
    std::vector<int32_t> lst(n_local);
    int32_t max_last = 0;
    for (int y = y0; y <= y1; ++y)
      for (int x = x0; x <= x1; ++x) {
        const int p = r.local(x, y);
        const int64_t pix = int64_t(y) * width + x;
        trans[p] = t_final[p] = trans_final[pix];
        g_t[p] = grad_trans[pix];
        lst[p] = last[pix];
        max_last = std::max(max_last, lst[p]);
        for (int f = 0; f < n_feat; ++f) g_pix[p * n_feat + f] = grad_out[f * n_pix + pix];
      }
    const int64_t begin = tl.offsets[tile];
    std::vector<T> g_feat(n_feat);
    for (int64_t k = max_last - 1; k >= 0; --k) {
      const int64_t g = tl.ids[begin + k];
      const int32_t* b = boxes + 4 * g;
      const int bx0 = std::max<int>(b[0], x0), bx1 = std::min<int>(b[1], x1);
      const int by0 = std::max<int>(b[2], y0), by1 = std::min<int>(b[3], y1);
      const T mx = means2d[2 * g], my = means2d[2 * g + 1];
      const T ca = conics[3 * g], cb = conics[3 * g + 1], cc = conics[3 * g + 2];
      const T op = opacities[g];
      const T* fg = feats + int64_t(n_feat) * g;
      T g_mx = 0, g_my = 0, g_a = 0, g_b = 0, g_c = 0, g_op = 0;
      std::fill(g_feat.begin(), g_feat.end(), T(0));
      bool touched = false;
      for (int y = by0; y <= by1; ++y) {
        const T dy = T(y) + T(0.5) - my;
        for (int x = bx0; x <= bx1; ++x) {
          const int p = r.local(x, y);
          if (k >= lst[p]) continue;
          const T dx = T(x) + T(0.5) - mx;
          const T power = gaussian_power(dx, dy, ca, cb, cc);
          const T gauss = std::exp(power);
          const T raw = op * gauss;
          const T alpha = std::min(T(0.99), raw);
          if (alpha < min_alpha) continue;
          touched = true;
          const T one_minus = T(1) - alpha;
          trans[p] /= one_minus;  // now T_i, the transmittance in front of this sample
          const T t_i = trans[p];
          const T w = alpha * t_i;
          T* bh = behind.data() + size_t(p) * n_feat;
          const T* gp = g_pix.data() + size_t(p) * n_feat;
          T g_alpha = 0;
          for (int f = 0; f < n_feat; ++f) {
            g_feat[f] += w * gp[f];
            g_alpha += gp[f] * t_i * (fg[f] - bh[f]);
            bh[f] = alpha * fg[f] + one_minus * bh[f];
          }
          g_alpha -= g_t[p] * t_final[p] / one_minus;
          if (raw >= T(0.99)) continue;  // clamped: no gradient to opacity or shape
          g_op += gauss * g_alpha;
          const T g_power = raw * g_alpha;
          // power = -0.5 (a dx^2 + c dy^2) - b dx dy with dx = px - mx
          g_mx += g_power * (ca * dx + cb * dy);
          g_my += g_power * (cc * dy + cb * dx);
          g_a += T(-0.5) * g_power * dx * dx;
          g_b += -g_power * dx * dy;
          g_c += T(-0.5) * g_power * dy * dy;
        }
      }
      if (!touched) continue;
      T* gg = gbuf + g * stride;
      gg[0] += g_mx;
      gg[1] += g_my;
      gg[2] += g_a;
      gg[3] += g_b;
      gg[4] += g_c;
      gg[5] += g_op;
      for (int f = 0; f < n_feat; ++f) gg[6 + f] += g_feat[f];
    }
  });
}


// ---- EWA projection, fused (prosplat/render/projection.py is its twin) ----------------------
// Per Gaussian, in double precision: camera-space mean, pixel mean, the 2D conic of
// M Mᵀ + 0.3 I with M = J·R_cam·R_q·diag(s) (J at x/z, y/z clamped to 1.3x the field of
// view), the dilated a, c (for the pixel boxes) and z. The backward pass recomputes the
// forward per Gaussian and walks it back by hand. cam = R (9, row-major), t (3), fx, fy, cx,
// cy, x/z low, x/z high, y/z low, y/z high, near, dilation.
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

void project_forward(int64_t n, const double* means, const double* quats, const double* scales,
                     const double* cam, double* means2d, double* conics, double* depth, double* ac,
                     int n_threads) {
  const ProjCam c(cam);
  const int64_t chunk = 4096, n_chunks = (n + chunk - 1) / chunk;
  parallel_tiles_static(n_chunks, n_threads, [&](int64_t ch, int) {
    ProjState st;
    for (int64_t g = ch * chunk; g < std::min(n, (ch + 1) * chunk); ++g) {
      proj_state(c, means + 3 * g, quats + 4 * g, scales + 3 * g, st);
      means2d[2 * g] = c.fx * st.xz + c.cx;
      means2d[2 * g + 1] = c.fy * st.yz + c.cy;
      const double a = st.a0 + c.dil, cc = st.c0 + c.dil, inv_det = 1.0 / st.det;
      conics[3 * g] = cc * inv_det;
      conics[3 * g + 1] = -st.b * inv_det;
      conics[3 * g + 2] = a * inv_det;
      depth[g] = st.z;
      ac[2 * g] = a;
      ac[2 * g + 1] = cc;
    }
  });
}

void project_backward(int64_t n, const double* means, const double* quats, const double* scales,
                      const double* cam, const double* g_m2d, const double* g_con,
                      const double* g_depth, double* g_means, double* g_quats, double* g_scales,
                      int n_threads) {
  const ProjCam c(cam);
  const int64_t chunk = 4096, n_chunks = (n + chunk - 1) / chunk;
  parallel_tiles_static(n_chunks, n_threads, [&](int64_t ch, int) {
    ProjState st;
    for (int64_t g = ch * chunk; g < std::min(n, (ch + 1) * chunk); ++g) {
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
    }
  });
}

}  // namespace

#define PROSPLAT_EXPORT extern "C" __attribute__((visibility("default")))

#define PROSPLAT_DEFINE(T, SUFFIX)                                                                 \
  PROSPLAT_EXPORT void prosplat_forward_##SUFFIX(                                                  \
      int64_t n_sorted, int n_feat, int width, int height, const T* means2d, const T* conics,     \
      const T* opacities, const T* feats, const int32_t* boxes, const int64_t* order, T* out,     \
      T* out_trans, int32_t* out_last, int n_threads) {                                           \
    forward<T>(n_sorted, n_feat, width, height, means2d, conics, opacities, feats, boxes, order, \
               out, out_trans, out_last, n_threads);                                              \
  }                                                                                               \
  PROSPLAT_EXPORT void prosplat_backward_##SUFFIX(                                                 \
      int64_t n_sorted, int n_feat, int width, int height, const T* means2d, const T* conics,     \
      const T* opacities, const T* feats, const int32_t* boxes, const int64_t* order,             \
      const T* trans_final, const int32_t* last, const T* grad_out, const T* grad_trans,          \
      T* grads, int64_t n_gauss, int n_threads) {                                                 \
    backward<T>(n_sorted, n_feat, width, height, means2d, conics, opacities, feats, boxes, order, \
                trans_final, last, grad_out, grad_trans, grads, n_gauss, n_threads);              \
  }

PROSPLAT_DEFINE(float, f32)
PROSPLAT_DEFINE(double, f64)

PROSPLAT_EXPORT void prosplat_project_forward_f64(int64_t n, const double* means,
                                                  const double* quats, const double* scales,
                                                  const double* cam, double* means2d,
                                                  double* conics, double* depth, double* ac,
                                                  int n_threads) {
  project_forward(n, means, quats, scales, cam, means2d, conics, depth, ac, n_threads);
}

PROSPLAT_EXPORT void prosplat_project_backward_f64(
    int64_t n, const double* means, const double* quats, const double* scales, const double* cam,
    const double* g_m2d, const double* g_con, const double* g_depth, double* g_means,
    double* g_quats, double* g_scales, int n_threads) {
  project_backward(n, means, quats, scales, cam, g_m2d, g_con, g_depth, g_means, g_quats,
                   g_scales, n_threads);
}

PROSPLAT_EXPORT int prosplat_abi_version() { return 1; }
