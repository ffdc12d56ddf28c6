#include "internal/gauss_legendre.h"

#include <cmath>
#include <map>
#include <memory>
#include <mutex>

#include "glog/logging.h"

namespace ccdpsf::internal {
namespace {

GaussLegendreRule ComputeRule(int n) {
  GaussLegendreRule rule;
  rule.nodes.resize(n);
  rule.weights.resize(n);
  for (int i = 0; i < (n + 1) / 2; ++i) {
    // Newton's method on P_n from the Tricomi initial guess for the i-th largest root.
    double x = std::cos(M_PI * (i + 0.75) / (n + 0.5));
    double dp = 0.0;
    for (int iter = 0; iter < 100; ++iter) {
      double p0 = 1.0, p1 = x;
      for (int k = 2; k <= n; ++k) {
        const double p2 = ((2.0 * k - 1.0) * x * p1 - (k - 1.0) * p0) / k;
        p0 = p1;
        p1 = p2;
      }
      const double pn = (n == 1) ? x : p1;
      const double pnm1 = (n == 1) ? 1.0 : p0;
      dp = n * (x * pn - pnm1) / (x * x - 1.0);
      const double dx = pn / dp;
      x -= dx;
      if (std::fabs(dx) < 1e-16) break;
    }
    const double w = 2.0 / ((1.0 - x * x) * dp * dp);
    rule.nodes[n - 1 - i] = x;
    rule.nodes[i] = -x;
    rule.weights[n - 1 - i] = w;
    rule.weights[i] = w;
  }
  return rule;
}

}  // namespace

const GaussLegendreRule& GaussLegendre(int n) {
  CHECK_GE(n, 1);
  static std::mutex mutex;
  static std::map<int, std::unique_ptr<GaussLegendreRule>> cache;
  std::lock_guard<std::mutex> lock(mutex);
  auto& slot = cache[n];
  if (!slot) slot = std::make_unique<GaussLegendreRule>(ComputeRule(n));
  return *slot;
}

}  // namespace ccdpsf::internal
