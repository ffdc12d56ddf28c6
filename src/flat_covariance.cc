// The pixel covariances of a flat pair (flat_covariance.h): masks, the difference image and
// its lag products.
#include "ccdpsf/flat_covariance.h"

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace ccdpsf {
namespace {

constexpr int kMaxClipRounds = 10;
// A residual from the neighbours' median needs this many neighbours in the region.
constexpr int kMinNeighbours = 3;

// The median of values[0..n) (reordered).
double Median(double* values, size_t n) {
  std::nth_element(values, values + n / 2, values + n);
  const double upper = values[n / 2];
  if (n % 2 == 1) return upper;
  return 0.5 * (upper + *std::max_element(values, values + n / 2));
}

}  // namespace

FlatPairCovariance MeasureFlatPair(const TransferFrame& a, const TransferFrame& b, double bias_adu,
                                   int max_lag) {
  FlatPairCovariance out;
  out.max_lag = max_lag;
  const int side = max_lag + 1;
  out.cov_adu2.assign(side * side, std::numeric_limits<double>::quiet_NaN());
  out.products.assign(side * side, 0);
  const Image& A = a.image->pixels;
  const Image& B = b.image->pixels;
  const int x0 = std::max(a.region.x_begin, b.region.x_begin);
  const int x1 = std::min(a.region.x_end, b.region.x_end);
  const int y0 = std::max(a.region.y_begin, b.region.y_begin);
  const int y1 = std::min(a.region.y_end, b.region.y_end);
  if (x1 <= x0 || y1 <= y0) return out;
  const int w = x1 - x0, h = y1 - y0;
  const size_t n = static_cast<size_t>(w) * h;
  out.region_pixels = static_cast<long long>(n);

  // Limits.
  std::vector<uint8_t> keep(n, 0);
  std::vector<double> mean(n, 0.0), diff(n, 0.0);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const size_t k = static_cast<size_t>(y) * w + x;
      const double va = A(x + x0, y + y0), vb = B(x + x0, y + y0);
      if (!std::isfinite(va) || !std::isfinite(vb)) {
        ++out.not_finite;
        continue;
      }
      const bool floor = va <= a.floor || vb <= b.floor;
      const bool ceiling = va >= a.ceiling || vb >= b.ceiling;
      out.at_floor += floor;
      out.at_ceiling += ceiling;
      if (floor || ceiling) continue;
      keep[k] = 1;
      mean[k] = 0.5 * (va + vb);
      diff[k] = va - vb;
    }
  }

  // Defects: the mean image's residual from its 8 neighbours' median.
  {
    std::vector<double> residual(n, std::numeric_limits<double>::quiet_NaN());
    std::vector<double> finite;
    finite.reserve(n);
    double around[8];
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        const size_t k = static_cast<size_t>(y) * w + x;
        if (!keep[k]) continue;
        size_t count = 0;
        for (int dy = -1; dy <= 1; ++dy) {
          for (int dx = -1; dx <= 1; ++dx) {
            const int xx = x + dx, yy = y + dy;
            if ((dx == 0 && dy == 0) || xx < 0 || yy < 0 || xx >= w || yy >= h) continue;
            const size_t kk = static_cast<size_t>(yy) * w + xx;
            if (keep[kk]) around[count++] = mean[kk];
          }
        }
        if (count < kMinNeighbours) continue;
        residual[k] = mean[k] - Median(around, count);
        finite.push_back(residual[k]);
      }
    }
    if (finite.size() >= 10) {
      const double centre = Median(finite.data(), finite.size());
      for (double& v : finite) v = std::fabs(v - centre);
      const double sd = 1.4826 * Median(finite.data(), finite.size());
      if (sd > 0.0) {
        for (size_t k = 0; k < n; ++k) {
          if (keep[k] && std::isfinite(residual[k]) &&
              std::fabs(residual[k] - centre) > kFlatDefectSigma * sd) {
            keep[k] = 0;
            ++out.defects;
          }
        }
      }
    }
  }

  // Outliers of the difference, clipped about its mean until nothing changes.
  double centre = 0.0;
  for (int round = 0; round < kMaxClipRounds; ++round) {
    double sum = 0.0, sum2 = 0.0;
    long long count = 0;
    for (size_t k = 0; k < n; ++k) {
      if (!keep[k]) continue;
      sum += diff[k];
      ++count;
    }
    if (count < 2) return out;
    centre = sum / count;
    for (size_t k = 0; k < n; ++k) {
      if (keep[k]) sum2 += (diff[k] - centre) * (diff[k] - centre);
    }
    const double limit = kTransferOutlierClipSigma * std::sqrt(sum2 / (count - 1));
    long long clipped = 0;
    for (size_t k = 0; k < n; ++k) {
      if (keep[k] && std::fabs(diff[k] - centre) > limit) {
        keep[k] = 0;
        ++clipped;
      }
    }
    out.outliers += clipped;
    if (clipped == 0) break;
  }

  // Means and the centred difference (0 where not kept, so that products need no branch).
  double sum_a = 0.0, sum_b = 0.0, sum_d = 0.0;
  long long kept = 0;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const size_t k = static_cast<size_t>(y) * w + x;
      if (!keep[k]) continue;
      sum_a += A(x + x0, y + y0);
      sum_b += B(x + x0, y + y0);
      sum_d += diff[k];
      ++kept;
    }
  }
  out.kept = kept;
  if (kept < 2) return out;
  out.mean_a_adu = sum_a / kept - bias_adu;
  out.mean_b_adu = sum_b / kept - bias_adu;
  out.mean_adu = 0.5 * (out.mean_a_adu + out.mean_b_adu);
  out.raw_mean_adu = out.mean_adu + bias_adu;
  const double mean_d = sum_d / kept;
  std::vector<double> v(n, 0.0), m(n, 0.0);
  for (size_t k = 0; k < n; ++k) {
    if (!keep[k]) continue;
    v[k] = diff[k] - mean_d;
    m[k] = 1.0;
  }

  // Lag products: (i, j) and, for i, j > 0, the mirror (i, -j).
  for (int j = 0; j <= max_lag; ++j) {
    for (int i = 0; i <= max_lag; ++i) {
      double sum = 0.0, count = 0.0;
      for (int mirror = 0; mirror < ((i > 0 && j > 0) ? 2 : 1); ++mirror) {
        // Pixel (x, y) with (x + i, y + dj); dj = j, or -j for the mirror.
        const int dj = mirror == 0 ? j : -j;
        const int y_begin = std::max(0, -dj), y_end = std::min(h, h - dj);
        for (int y = y_begin; y < y_end; ++y) {
          const double* row = &v[static_cast<size_t>(y) * w];
          const double* other = &v[static_cast<size_t>(y + dj) * w + i];
          const double* row_m = &m[static_cast<size_t>(y) * w];
          const double* other_m = &m[static_cast<size_t>(y + dj) * w + i];
          for (int x = 0; x + i < w; ++x) {
            sum += row[x] * other[x];
            count += row_m[x] * other_m[x];
          }
        }
      }
      const int l = j * side + i;
      out.products[l] = static_cast<long long>(count);
      if (count > 0.0) out.cov_adu2[l] = sum / (2.0 * count);
    }
  }
  return out;
}

}  // namespace ccdpsf
