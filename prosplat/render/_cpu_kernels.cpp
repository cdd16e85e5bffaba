// Tile-based alpha compositing of projected 2D Gaussians on the CPU: forward (one stream or a
// pair of opacity streams) and backward.
//
// The projection is in torch or in _cpu_project.cpp (compiled into the same library); this
// file does the part torch cannot do fast: per-pixel front-to-back compositing with early
// termination.
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
// (from an opacity-aware radius: projection.pixel_boxes or its twin in _cpu_project.cpp), so
// culling never changes the image.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "_cpu_parallel.h"

namespace {

using prosplat_cpu::parallel_chunks;
using prosplat_cpu::parallel_tiles;
using prosplat_cpu::parallel_tiles_static;

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

// S compositing streams of the same depth-sorted Gaussians that differ only in their
// opacities (stream s reads opacities[s], writes out[s], out_trans[s], out_last[s]). The
// binning, the box walk and the exp of each sample are shared; each stream keeps its own
// accumulators and transmittance and stops on its own threshold. Every stream runs exactly
// the arithmetic of a one-stream pass (the same exp value, the same products in the same
// order), so a pair equals two separate composites bitwise. Why: a view that favours one
// input (render_pair) composites one projection twice, and the exp is most of the work.
template <typename T, int S>
void forward(int64_t n_sorted, int n_feat, int width, int height, const T* means2d, const T* conics,
             const T* const* opacities, const T* feats, const int32_t* boxes, const int64_t* order,
             T* const* out, T* const* out_trans, int32_t* const* out_last, int n_threads) {
  const TileLists tl = build_tile_lists(n_sorted, order, boxes, width, height);
  const int64_t n_pix = int64_t(width) * height;
  const T min_alpha = T(1) / T(255);
  parallel_tiles(int64_t(tl.tiles_x) * tl.tiles_y, n_threads, [&](int64_t tile, int) {
    constexpr int kPix = kTile * kTile;
    const TileRect r = tile_rect(tl, tile, width, height);
    const int x0 = r.x0, y0 = r.y0, x1 = r.x1, y1 = r.y1;
    T trans[S][kPix];
    T acc[S][kPix * 8];
    std::vector<T> acc_big[S];  // only when n_feat > 8
    T* accp[S];
    int32_t last[S][kPix];
    bool done[S][kPix];
    bool all_done[kPix];  // every stream done: the sample is not evaluated at all
    const int n_local = r.size();
    for (int s = 0; s < S; ++s) {
      accp[s] = acc[s];
      if (n_feat > 8) {
        acc_big[s].assign(size_t(kPix) * n_feat, T(0));
        accp[s] = acc_big[s].data();
      } else {
        std::fill(acc[s], acc[s] + kPix * n_feat, T(0));
      }
      std::fill(trans[s], trans[s] + kPix, T(1));
      std::fill(last[s], last[s] + kPix, 0);
      std::fill(done[s], done[s] + kPix, false);
    }
    std::fill(all_done, all_done + kPix, false);
    int n_any = n_local;  // pixels where some stream is still active
    const int64_t begin = tl.offsets[tile], end = tl.offsets[tile + 1];
    for (int64_t k = begin; k < end && n_any > 0; ++k) {
      const int64_t g = tl.ids[k];
      const int32_t* b = boxes + 4 * g;
      const int bx0 = std::max<int>(b[0], x0), bx1 = std::min<int>(b[1], x1);
      const int by0 = std::max<int>(b[2], y0), by1 = std::min<int>(b[3], y1);
      const T mx = means2d[2 * g], my = means2d[2 * g + 1];
      const T ca = conics[3 * g], cb = conics[3 * g + 1], cc = conics[3 * g + 2];
      T op[S];
      for (int s = 0; s < S; ++s) op[s] = opacities[s][g];
      const T* fg = feats + int64_t(n_feat) * g;
      for (int y = by0; y <= by1; ++y) {
        const T dy = T(y) + T(0.5) - my;
        for (int x = bx0; x <= bx1; ++x) {
          const int p = r.local(x, y);
          if (all_done[p]) continue;
          const T dx = T(x) + T(0.5) - mx;
          const T gauss = std::exp(gaussian_power(dx, dy, ca, cb, cc));
          for (int s = 0; s < S; ++s) {
            if (done[s][p]) continue;
            const T alpha = std::min(T(0.99), op[s] * gauss);
            if (alpha < min_alpha) continue;
            const T next_t = trans[s][p] * (T(1) - alpha);
            if (next_t < T(1e-4)) {
              done[s][p] = true;
              bool all = true;
              for (int u = 0; u < S; ++u) all = all && done[u][p];
              if (all) {
                all_done[p] = true;
                --n_any;
              }
              continue;
            }
            const T w = alpha * trans[s][p];
            T* ap = accp[s] + p * n_feat;
            for (int f = 0; f < n_feat; ++f) ap[f] += w * fg[f];
            trans[s][p] = next_t;
            last[s][p] = int32_t(k - begin + 1);
          }
        }
      }
    }
    for (int s = 0; s < S; ++s)
      for (int y = y0; y <= y1; ++y)
        for (int x = x0; x <= x1; ++x) {
          const int p = r.local(x, y);
          const int64_t pix = int64_t(y) * width + x;
          for (int f = 0; f < n_feat; ++f) out[s][f * n_pix + pix] = accp[s][p * n_feat + f];
          out_trans[s][pix] = trans[s][p];
          out_last[s][pix] = last[s][p];
        }
  });
}

// A render from a composite of colour and depth (out [4, n_pix], transmittance [n_pix]) over
// the background bg [3]: rgb = out[0..3) + T·bg, alpha = 1 - T, depth = out[3] / max(alpha,
// 1e-6) where alpha > 0, else 0. prosplat.render.cpu.finish_reference's torch operations one
// by one, each rounded in T as torch rounds it (its scalars are T too), so the same values;
// one pass over the pixels instead of ten.
template <typename T>
void finish(int64_t n_pix, const T* out, const T* trans, const T* bg, T* rgb, T* alpha, T* depth,
            int n_threads) {
  parallel_chunks(n_pix, 16384, n_threads, [&](int64_t i) {
    const T t = trans[i];
    for (int ch = 0; ch < 3; ++ch) rgb[ch * n_pix + i] = out[ch * n_pix + i] + t * bg[ch];
    const T a = T(1) - t;
    alpha[i] = a;
    depth[i] = a > T(0) ? out[3 * n_pix + i] / std::max(a, T(1e-6)) : T(0);
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


}  // namespace

#define PROSPLAT_EXPORT extern "C" __attribute__((visibility("default")))

#define PROSPLAT_DEFINE(T, SUFFIX)                                                                 \
  PROSPLAT_EXPORT void prosplat_forward_##SUFFIX(                                                  \
      int64_t n_sorted, int n_feat, int width, int height, const T* means2d, const T* conics,     \
      const T* opacities, const T* feats, const int32_t* boxes, const int64_t* order, T* out,     \
      T* out_trans, int32_t* out_last, int n_threads) {                                           \
    const T* ops[1] = {opacities};                                                                \
    T* outs[1] = {out};                                                                           \
    T* transs[1] = {out_trans};                                                                   \
    int32_t* lasts[1] = {out_last};                                                               \
    forward<T, 1>(n_sorted, n_feat, width, height, means2d, conics, ops, feats, boxes, order,    \
                  outs, transs, lasts, n_threads);                                                \
  }                                                                                               \
  PROSPLAT_EXPORT void prosplat_forward_pair_##SUFFIX(                                             \
      int64_t n_sorted, int n_feat, int width, int height, const T* means2d, const T* conics,     \
      const T* opacities_a, const T* opacities_b, const T* feats, const int32_t* boxes,           \
      const int64_t* order, T* out_a, T* trans_a, int32_t* last_a, T* out_b, T* trans_b,          \
      int32_t* last_b, int n_threads) {                                                           \
    const T* ops[2] = {opacities_a, opacities_b};                                                 \
    T* outs[2] = {out_a, out_b};                                                                  \
    T* transs[2] = {trans_a, trans_b};                                                            \
    int32_t* lasts[2] = {last_a, last_b};                                                         \
    forward<T, 2>(n_sorted, n_feat, width, height, means2d, conics, ops, feats, boxes, order,    \
                  outs, transs, lasts, n_threads);                                                \
  }                                                                                               \
  PROSPLAT_EXPORT void prosplat_backward_##SUFFIX(                                                 \
      int64_t n_sorted, int n_feat, int width, int height, const T* means2d, const T* conics,     \
      const T* opacities, const T* feats, const int32_t* boxes, const int64_t* order,             \
      const T* trans_final, const int32_t* last, const T* grad_out, const T* grad_trans,          \
      T* grads, int64_t n_gauss, int n_threads) {                                                 \
    backward<T>(n_sorted, n_feat, width, height, means2d, conics, opacities, feats, boxes, order, \
                trans_final, last, grad_out, grad_trans, grads, n_gauss, n_threads);              \
  }

#define PROSPLAT_DEFINE_FINISH(T, SUFFIX)                                                          \
  PROSPLAT_EXPORT void prosplat_finish_##SUFFIX(int64_t n_pix, const T* out, const T* trans,       \
                                                const T* bg, T* rgb, T* alpha, T* depth,          \
                                                int n_threads) {                                  \
    finish<T>(n_pix, out, trans, bg, rgb, alpha, depth, n_threads);                               \
  }

PROSPLAT_DEFINE_FINISH(float, f32)
PROSPLAT_DEFINE_FINISH(double, f64)
PROSPLAT_DEFINE(float, f32)
PROSPLAT_DEFINE(double, f64)

PROSPLAT_EXPORT int prosplat_abi_version() { return 2; }
