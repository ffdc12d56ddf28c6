// ParallelFor (src/internal/parallel_for.h): every index once, workers in range, any count.
#include "internal/parallel_for.h"

#include <atomic>
#include <mutex>
#include <set>
#include <vector>

#include "gtest/gtest.h"

namespace ccdpsf::internal {
namespace {

TEST(ParallelFor, EveryIndexExactlyOnceOnWorkersInRange) {
  for (int n : {0, 1, 2, 3, 17, 1000}) {
    for (int threads : {-3, 0, 1, 2, 4, 64}) {
      std::vector<std::atomic<int>> calls(n);
      std::mutex mutex;
      std::set<int> workers;
      ParallelFor(n, threads, [&](int i, int worker) {
        ASSERT_GE(i, 0);
        ASSERT_LT(i, n);
        calls[i].fetch_add(1);
        std::lock_guard<std::mutex> lock(mutex);
        workers.insert(worker);
      });
      for (int i = 0; i < n; ++i) EXPECT_EQ(calls[i].load(), 1) << "n " << n << " index " << i;
      for (int w : workers) {
        EXPECT_GE(w, 0);
        EXPECT_LT(w, std::max(1, std::min(threads, n))) << "n " << n << " threads " << threads;
      }
    }
  }
}

// One worker runs one task at a time, so state kept per worker needs no lock: each worker's
// counter, bumped without synchronisation, adds up to n.
TEST(ParallelFor, PerWorkerStateNeedsNoLock) {
  const int n = 5000, threads = 3;
  std::vector<long> per_worker(threads, 0);
  ParallelFor(n, threads, [&](int, int worker) { ++per_worker[worker]; });
  long total = 0;
  for (long c : per_worker) total += c;
  EXPECT_EQ(total, n);
}

}  // namespace
}  // namespace ccdpsf::internal
