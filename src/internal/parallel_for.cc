#include "internal/parallel_for.h"

#include <algorithm>
#include <atomic>
#include <system_error>
#include <thread>
#include <vector>

namespace ccdpsf::internal {

void ParallelFor(int n, int threads, const std::function<void(int index, int worker)>& task) {
  if (n <= 0) return;
  std::atomic<int> next{0};
  auto worker = [&](int w) {
    for (int i = next.fetch_add(1); i < n; i = next.fetch_add(1)) task(i, w);
  };
  const int count = std::clamp(threads, 1, n);
  std::vector<std::thread> pool;
  for (int w = 1; w < count; ++w) {
    try {
      pool.emplace_back(worker, w);
    } catch (const std::system_error&) {
      break;  // the system refuses a thread: the workers started do the rest
    }
  }
  worker(0);
  for (std::thread& t : pool) t.join();
}

}  // namespace ccdpsf::internal
