// The std::thread helpers both kernel files share (_cpu_kernels.cpp, _cpu_project.cpp): no
// OpenMP runtime to clash with torch's. Templates only, so each file compiles its own copy.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <thread>
#include <vector>

namespace prosplat_cpu {

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

// fn(t, tid) for t in [0, n_tiles), the next tile to whichever thread is free.
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

// fn(i) for i in [0, n), in chunks of ``chunk`` split as parallel_tiles_static splits tiles.
template <typename Fn>
void parallel_chunks(int64_t n, int64_t chunk, int n_threads, Fn fn) {
  parallel_tiles_static((n + chunk - 1) / chunk, n_threads, [&](int64_t ch, int) {
    for (int64_t i = ch * chunk; i < std::min(n, (ch + 1) * chunk); ++i) fn(i);
  });
}

}  // namespace prosplat_cpu
