// Photon-transfer gain and read noise (photon_transfer.h): samples from frame pairs or from
// single frames, level bins, the ADC-limit rules, and a weighted straight-line fit.
#include "ccdpsf/photon_transfer.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <sstream>

#include "ccdpsf/exposure.h"
#include "internal/json_number.h"

namespace ccdpsf {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

// Samples touching the floor: kTransferMaxFloorFraction (photon_transfer_frames.h).
constexpr double kMaxClippedFraction = kTransferMaxFloorFraction;
// Levels above kTransferFullScaleFraction of the ADC's range are left out.
constexpr double kFullScaleFraction = kTransferFullScaleFraction;
// Outliers are clipped at kTransferOutlierClipSigma sd about their cell's mean (the loss
// of variance is not corrected).
constexpr double kOutlierClipSigma = kTransferOutlierClipSigma;
constexpr int kMaxClipRounds = 10;
// A bin needs this many samples after the selection to give a point (its variance is then
// known to sqrt(2 / 29) = 26 %; the weights account for that).
constexpr long long kMinSamplesPerPoint = 30;
// Single frame: a block is smooth when its ring's residual variance about a plane is at most
// this multiple of the noise variance (photon_transfer.h says why 1.5).
constexpr double kSmoothFactor = 1.5;
// Rounds of (accumulate, fit, take the fit as the noise model) at most.
constexpr int kMaxSelectionRounds = 6;
// Pairs: a pixel is used only where the difference cancelled what is fixed, judged by its 8
// neighbours' differences (independent of the pixel's own noise, so the choice does not bias
// its variance). First round, with no noise model: their t statistic, mean / (sd / sqrt(8)),
// a Student t with 7 dof under noise alone, must be within kPairFirstT (exceeded in 0.16 %
// of cases). Later rounds: their mean must be within kPairStructureSd sds of the cell's mean
// difference, the sd being sqrt(2 var / 8) at their level (exceeded in 0.3 % of cases). A
// spot that moved between the frames, or changed its brightness, leaves coherent lobes that
// fail this by far.
constexpr double kPairFirstT = 5.0;
constexpr double kPairStructureSd = 3.0;
// The slope must exceed this many sd for a gain to be given at all: 3 for many points; for
// few, the Student t quantile with the fit's dof at the same one-sided tail (0.135 %), since
// the sd then comes from a chi2 of few degrees of freedom (StudentQuantile3Sd).
constexpr double kMinSlopeSignificance = 3.0;
// A point further than this many of its counting sds from the line through the others is
// not noise alone and is dropped (FitLineRejecting).
constexpr double kRejectPointSd = 6.0;
// The read noise is given when its variance is positive by this many sd.
constexpr double kReadNoiseSignificance = 2.0;
// A quadratic term beyond this many sd is reported as a bent transfer curve.
constexpr double kCurvatureSignificance = 3.0;
// A pair whose mean difference grows with the level by more than this fraction of the level
// (and by more than 3 of its sd) was probably not taken under the same illumination.
constexpr double kMaxPairIlluminationChange = 0.05;
// A gain whose sd exceeds this fraction of it is flagged as uncertain.
constexpr double kUncertainGain = 0.1;

// The upper 0.135 % point of Student's t with `dof` degrees of freedom: tabulated (computed
// by numerical integration of the density) up to 8, the Cornish-Fisher expansion around
// z = 3 beyond (error < 0.01 there), and z = 3 itself with no dof.
double StudentQuantile3Sd(int dof) {
  static const double kTable[] = {235.80, 19.207, 9.219, 6.620, 5.507, 4.904, 4.530, 4.277};
  if (dof <= 0) return kMinSlopeSignificance;
  if (dof <= 8) return kTable[dof - 1];
  const double z = kMinSlopeSignificance, n = dof;
  return z + (z * z * z + z) / (4 * n) +
         (5 * std::pow(z, 5) + 16 * z * z * z + 3 * z) / (96 * n * n) +
         (3 * std::pow(z, 7) + 19 * std::pow(z, 5) + 17 * z * z * z - 15 * z) / (384 * n * n * n);
}

enum SampleFlags : uint8_t { kTouchesFloor = 1, kTouchesCeiling = 2 };

// One difference value and where it sits. Floats keep a large frame's samples compact; the
// values are whole ADU or small sums of them, exact in a float below 2^24.
struct Sample {
  float bin_level;     // binning level [ADU]: the neighbours' (pairs) or the ring's (single)
  float level;         // the sample's own mean level [ADU]
  float value;         // A - B (pairs) or dd (single) [ADU]
  float structure;     // single frame: the ring's residual variance about a plane [ADU^2];
                       // pairs: the mean of the 8 neighbours' differences A - B [ADU]
  float structure_sd;  // pairs: the sd of those 8 differences [ADU]; 0 for single frames
  uint8_t flags;
};

// The samples of one pair or one frame. A pixel's variance is var(value) / divisor.
struct Source {
  std::string label;
  std::vector<Sample> samples;
  double divisor = 2.0;
};

using Prepared = TransferFrame;

// printf of one number, for messages.
std::string Format(const char* format, double value) {
  char text[256];
  std::snprintf(text, sizeof(text), format, value);
  return text;
}

// Levels and fractions in messages: 4 significant digits.
std::string Num(double value) { return Format("%.4g", value); }

// Pairs: one sample per pixel with all 8 neighbours inside the region.
Source PairSamples(const Prepared& a, const Prepared& b) {
  Source source;
  source.divisor = 2.0;
  const Image& A = a.image->pixels;
  const Image& B = b.image->pixels;
  // The region both frames share.
  PixelRegion r;
  r.x_begin = std::max(a.region.x_begin, b.region.x_begin);
  r.x_end = std::min(a.region.x_end, b.region.x_end);
  r.y_begin = std::max(a.region.y_begin, b.region.y_begin);
  r.y_end = std::min(a.region.y_end, b.region.y_end);
  if (r.Width() < 3 || r.Height() < 3) return source;
  Image mean(A.nx, A.ny, kNaN), diff(A.nx, A.ny, kNaN);
  for (int y = r.y_begin; y < r.y_end; ++y) {
    for (int x = r.x_begin; x < r.x_end; ++x) {
      mean(x, y) = 0.5 * (A(x, y) + B(x, y));
      diff(x, y) = A(x, y) - B(x, y);
    }
  }
  source.samples.reserve(static_cast<size_t>(r.Width() - 2) * (r.Height() - 2));
  for (int y = r.y_begin + 1; y + 1 < r.y_end; ++y) {
    for (int x = r.x_begin + 1; x + 1 < r.x_end; ++x) {
      const double va = A(x, y), vb = B(x, y);
      if (!std::isfinite(va) || !std::isfinite(vb)) continue;
      double sum = 0.0, sum_diff = 0.0, sum_diff2 = 0.0;
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          if (dx == 0 && dy == 0) continue;
          sum += mean(x + dx, y + dy);
          sum_diff += diff(x + dx, y + dy);
          sum_diff2 += diff(x + dx, y + dy) * diff(x + dx, y + dy);
        }
      }
      if (!std::isfinite(sum) || !std::isfinite(sum_diff)) continue;
      Sample s;
      s.bin_level = static_cast<float>(sum / 8.0);
      s.level = static_cast<float>(0.5 * (va + vb));
      s.value = static_cast<float>(va - vb);
      s.structure = static_cast<float>(sum_diff / 8.0);
      s.structure_sd = static_cast<float>(
          std::sqrt(std::max(0.0, (sum_diff2 - sum_diff * sum_diff / 8.0) / 7.0)));
      s.flags = 0;
      if (va <= a.floor || vb <= b.floor) s.flags |= kTouchesFloor;
      if (va >= a.ceiling || vb >= b.ceiling) s.flags |= kTouchesCeiling;
      source.samples.push_back(s);
    }
  }
  return source;
}

// Single frame: one sample per 2 x 2 block whose 6 x 6 box lies inside the region. Offsets
// of the box run from -2 to +3 about the block's first pixel; u, v are measured from the
// block's centre (+0.5, +0.5), so the ring is symmetric and the plane's coefficients
// decouple: c0 = ring mean, c1 = sum(u p) / sum(u^2), c2 = sum(v p) / sum(v^2).
Source SingleFrameSamples(const Prepared& f) {
  Source source;
  source.divisor = 4.0;
  const Image& P = f.image->pixels;
  const PixelRegion& r = f.region;
  struct RingPixel {
    int dx, dy;
    double u, v;
  };
  std::vector<RingPixel> ring;
  double suu = 0.0, svv = 0.0;
  for (int dy = -2; dy <= 3; ++dy) {
    for (int dx = -2; dx <= 3; ++dx) {
      if ((dx == 0 || dx == 1) && (dy == 0 || dy == 1)) continue;
      const RingPixel rp{dx, dy, dx - 0.5, dy - 0.5};
      suu += rp.u * rp.u;
      svv += rp.v * rp.v;
      ring.push_back(rp);
    }
  }
  const double ring_dof = static_cast<double>(ring.size()) - 3.0;  // 32 - 3 = 29
  for (int y = r.y_begin + 2; y + 3 < r.y_end; y += 2) {
    for (int x = r.x_begin + 2; x + 3 < r.x_end; x += 2) {
      const double p00 = P(x, y), p10 = P(x + 1, y), p01 = P(x, y + 1), p11 = P(x + 1, y + 1);
      if (!std::isfinite(p00 + p10 + p01 + p11)) continue;
      double sum = 0.0, sum2 = 0.0, su = 0.0, sv = 0.0;
      bool ring_at_ceiling = false;
      const double centre = p00;  // shift for the sums of squares
      for (const RingPixel& rp : ring) {
        const double v = P(x + rp.dx, y + rp.dy);
        ring_at_ceiling |= v >= f.ceiling;
        const double d = v - centre;
        sum += d;
        sum2 += d * d;
        su += rp.u * d;
        sv += rp.v * d;
      }
      if (!std::isfinite(sum2)) continue;
      const double n = static_cast<double>(ring.size());
      const double c1 = su / suu, c2 = sv / svv;
      const double residual = sum2 - sum * sum / n - c1 * c1 * suu - c2 * c2 * svv;
      Sample s;
      s.bin_level = static_cast<float>(centre + sum / n);
      s.level = static_cast<float>(0.25 * (p00 + p10 + p01 + p11));
      s.value = static_cast<float>((p10 - p00) - (p11 - p01));
      s.structure = static_cast<float>(std::max(0.0, residual) / ring_dof);
      s.structure_sd = 0.0f;
      s.flags = 0;
      if (std::min(std::min(p00, p10), std::min(p01, p11)) <= f.floor) s.flags |= kTouchesFloor;
      if (std::max(std::max(p00, p10), std::max(p01, p11)) >= f.ceiling || ring_at_ceiling) {
        s.flags |= kTouchesCeiling;
      }
      source.samples.push_back(s);
    }
  }
  return source;
}

// Level bins: the union of equal-count edges (quantiles: where the pixels are) and edges
// equally spaced in sqrt(level - lowest) (the noise grows as sqrt(level), so these spread
// points evenly in signal-to-noise and reach the bright, sparse levels that give the slope
// its lever arm), over the binning levels of the samples that touch neither limit. Bins
// with fewer than min_samples samples are merged upwards (the top one downwards). Samples
// beyond the outer edges fall into the outer bins.
std::vector<double> BuildBins(const std::vector<Source>& sources, int num_bins, int min_samples) {
  std::vector<float> levels;
  for (const Source& s : sources) {
    for (const Sample& x : s.samples) {
      if (x.flags == 0) levels.push_back(x.bin_level);
    }
  }
  if (levels.size() < 2) return {};
  std::sort(levels.begin(), levels.end());
  const double lo = levels.front(), hi = levels.back();
  if (!(hi > lo)) return {};
  std::vector<double> edges = {lo, hi};
  for (int k = 1; k < num_bins; ++k) {
    edges.push_back(levels[levels.size() * k / num_bins]);
    const double t = static_cast<double>(k) / num_bins;
    edges.push_back(lo + (hi - lo) * t * t);
  }
  std::sort(edges.begin(), edges.end());
  const double tiny = 1e-9 * (hi - lo);
  std::vector<double> unique_edges;
  for (double e : edges) {
    if (unique_edges.empty() || e - unique_edges.back() > tiny) unique_edges.push_back(e);
  }
  edges = unique_edges;
  // Count the samples that enter the statistics (all but those at the top).
  auto count_bins = [&](const std::vector<double>& e) {
    std::vector<long long> counts(e.size() - 1, 0);
    for (const Source& s : sources) {
      for (const Sample& x : s.samples) {
        if (x.flags & kTouchesCeiling) continue;
        long k =
            std::upper_bound(e.begin(), e.end(), static_cast<double>(x.bin_level)) - e.begin() - 1;
        k = std::clamp<long>(k, 0, static_cast<long>(counts.size()) - 1);
        ++counts[k];
      }
    }
    return counts;
  };
  std::vector<long long> counts = count_bins(edges);
  std::vector<double> merged = {edges.front()};
  long long running = 0;
  for (size_t k = 0; k < counts.size(); ++k) {
    running += counts[k];
    if (running >= min_samples || k + 1 == counts.size()) {
      merged.push_back(edges[k + 1]);
      running = 0;
    }
  }
  // A short top bin joins the one below.
  if (merged.size() > 2) {
    std::vector<long long> c = count_bins(merged);
    if (c.back() < min_samples) merged.erase(merged.end() - 2);
  }
  return merged;
}

int BinOf(const std::vector<double>& edges, double level) {
  long k = std::upper_bound(edges.begin(), edges.end(), level) - edges.begin() - 1;
  return static_cast<int>(std::clamp<long>(k, 0, static_cast<long>(edges.size()) - 2));
}

// A provisional noise model var = a + b m [ADU^2, per pixel], from the previous round's fit.
struct NoiseModel {
  bool ok = false;
  double a = 0.0, b = 0.0;
  double floor = 1e-6;  // no sample is expected to be quieter than this [ADU^2]
  double At(double level) const { return std::max(a + b * level, floor); }
};

// Per (source, bin) accumulation with iterative outlier clipping.
struct Cell {
  long long selected = 0;  // samples selected (incl. clipped outliers), not at the top
  long long floor = 0;     // of those, touching the floor
  long long ceiling = 0;   // samples touching the top (not in `selected`)
  long long n = 0;         // used after clipping
  double sum = 0.0, sum2 = 0.0, sum_level = 0.0;
  double sum_w = 0.0, sum_w2 = 0.0;  // expected variances of the samples used (with a model)
  double mean = 0.0, var = 0.0;
};

// A cell's mean difference [ADU], with its sd, and mean level [ADU].
struct CellMean {
  double diff = std::numeric_limits<double>::quiet_NaN();
  double diff_sd = std::numeric_limits<double>::quiet_NaN();
  double level = std::numeric_limits<double>::quiet_NaN();
};

struct Accumulated {
  std::vector<PtcPoint> points;
  // Per source, per bin: mean difference and mean level of the cell (NaN if empty), for the
  // pair illumination check.
  std::vector<std::vector<CellMean>> cell_means;
};

// Without a model (the first round) a sample is an outlier beyond kOutlierClipSigma of its
// cell's sd. With one, beyond kOutlierClipSigma of the sd expected at its own level: a bin
// made on the neighbours' level can hold pixels of very different levels (a sharp spot's
// core beside its background), whose differences are not outliers, and a cell's single sd
// would clip the bright ones and bias the variance low. For the same reason a cell's degrees
// of freedom are Satterthwaite's effective number (sum v_i)^2 / sum v_i^2 - 1, with v_i the
// variance expected at each sample's level: n - 1 when the levels agree, fewer when a few
// noisy samples dominate the cell.
Accumulated Accumulate(const std::vector<Source>& sources, const std::vector<double>& edges,
                       const std::vector<std::vector<uint8_t>>& selected, const NoiseModel& model) {
  const int nbins = static_cast<int>(edges.size()) - 1;
  Accumulated out;
  out.points.assign(nbins, PtcPoint{});
  std::vector<double> level_sum(nbins, 0.0), var_sum(nbins, 0.0);
  std::vector<long long> sel(nbins, 0), flo(nbins, 0), ceil(nbins, 0);
  for (size_t si = 0; si < sources.size(); ++si) {
    const Source& src = sources[si];
    std::vector<Cell> cells(nbins);
    std::vector<int> bin(src.samples.size());
    std::vector<double> scale(src.samples.size(), 1.0);  // expected sd of the value
    for (size_t i = 0; i < src.samples.size(); ++i) {
      const Sample& s = src.samples[i];
      bin[i] = BinOf(edges, s.bin_level);
      if (model.ok) scale[i] = std::sqrt(src.divisor * model.At(s.level));
      Cell& c = cells[bin[i]];
      if (s.flags & kTouchesCeiling) {
        ++c.ceiling;
        continue;
      }
      if (!selected[si][i]) continue;
      ++c.selected;
      if (s.flags & kTouchesFloor) ++c.floor;
    }
    // Clipping rounds: the first uses every selected sample, each later one those within
    // kOutlierClipSigma of the previous round's mean; stop when no cell's count changes.
    std::vector<double> centre(nbins, 0.0), width(nbins, kInf);
    auto kept = [&](size_t i) {
      const Sample& s = src.samples[i];
      if ((s.flags & kTouchesCeiling) || !selected[si][i]) return false;
      const int k = bin[i];
      return std::fabs(s.value - centre[k]) <= width[k] * scale[i];
    };
    for (int round = 0; round < kMaxClipRounds; ++round) {
      for (Cell& c : cells) c.n = 0, c.sum = c.sum2 = c.sum_level = c.sum_w = c.sum_w2 = 0.0;
      for (size_t i = 0; i < src.samples.size(); ++i) {
        if (!kept(i)) continue;
        const Sample& s = src.samples[i];
        Cell& c = cells[bin[i]];
        ++c.n;
        c.sum += s.value;
        c.sum2 += static_cast<double>(s.value) * s.value;
        c.sum_level += s.level;
        const double w = scale[i] * scale[i];
        c.sum_w += w;
        c.sum_w2 += w * w;
      }
      for (int k = 0; k < nbins; ++k) {
        Cell& c = cells[k];
        if (c.n < 2) continue;
        c.mean = c.sum / c.n;
        c.var = std::max(0.0, (c.sum2 - c.sum * c.mean) / (c.n - 1));
        centre[k] = c.mean;
        width[k] = kOutlierClipSigma * (model.ok ? 1.0 : std::sqrt(c.var));
      }
      std::vector<long long> next(nbins, 0);
      for (size_t i = 0; i < src.samples.size(); ++i) next[bin[i]] += kept(i);
      bool same = true;
      for (int k = 0; k < nbins; ++k) same &= cells[k].n < 2 || next[k] == cells[k].n;
      if (same) break;
    }
    std::vector<CellMean> means(nbins);
    for (int k = 0; k < nbins; ++k) {
      const Cell& c = cells[k];
      sel[k] += c.selected;
      flo[k] += c.floor;
      ceil[k] += c.ceiling;
      if (c.n < 2) continue;
      PtcPoint& p = out.points[k];
      const double n_eff = model.ok && c.sum_w2 > 0.0 ? c.sum_w * c.sum_w / c.sum_w2 : c.n;
      const double dof = std::max(1.0, std::min<double>(n_eff, c.n) - 1.0);
      p.pixels += c.n;
      p.dof += dof;
      var_sum[k] += dof * c.var / src.divisor;
      level_sum[k] += c.sum_level;
      means[k] = {c.mean, std::sqrt(c.var / c.n), c.sum_level / c.n};
    }
    out.cell_means.push_back(std::move(means));
  }
  for (int k = 0; k < nbins; ++k) {
    PtcPoint& p = out.points[k];
    p.bin_low_adu = edges[k];
    p.bin_high_adu = edges[k + 1];
    p.mean_adu = p.pixels > 0 ? level_sum[k] / p.pixels : kNaN;
    p.variance_adu2 = p.dof > 0 ? var_sum[k] / p.dof : kNaN;
    p.floor_fraction = sel[k] > 0 ? static_cast<double>(flo[k]) / sel[k] : 0.0;
    p.ceiling_fraction =
        sel[k] + ceil[k] > 0 ? static_cast<double>(ceil[k]) / (sel[k] + ceil[k]) : 0.0;
  }
  return out;
}

// The limit rules of photon_transfer.h. `ceiling` is the lowest top of the frames (+inf when
// none), `step` the ADC's step (0 for floating point). Fills used / excluded_because. Returns
// the lowest binning level kept above the floor's bins in *floor_cut (NaN when no bin was
// excluded for the floor, +inf when every bin was) and the lowest level excluded for the top
// in *top_cut (NaN when none).
//
// The floor is judged by counting: the clipped value is known and many pixels sit on it. The
// top is judged by the level: pixels at the top are dropped as they come, but because bins
// are made on the neighbours' level, a saturated spot's pixels land in bins of any level, so
// counting them would condemn levels far below the top. A level is kept when less than
// 0.1 % of its pixels' noise distribution (kTransferTailSd) reaches the top.
constexpr double kTailSd = kTransferTailSd;

void ApplyRules(std::vector<PtcPoint>* points, double ceiling, double step, double full_scale_level,
                double* floor_cut, double* top_cut) {
  const int n = static_cast<int>(points->size());
  for (PtcPoint& p : *points) {
    p.used = true;
    p.excluded_because.clear();
  }
  // The floor's cascade runs up from the lowest bin and stops at the first bin that is clear
  // of it: noise reaches the floor more often the lower the level. A bin higher up that
  // touches the floor does so through structure (a bright arc beside dark pixels), not
  // through its level's noise, and is excluded alone.
  int highest_floor = -1;
  while (highest_floor + 1 < n &&
         ((*points)[highest_floor + 1].floor_fraction > kMaxClippedFraction ||
          (*points)[highest_floor + 1].pixels == 0)) {
    ++highest_floor;
  }
  int lowest_top = n;
  for (int k = n - 1; k >= 0; --k) {
    const PtcPoint& p = (*points)[k];
    if (p.pixels > 0 && std::isfinite(p.variance_adu2) &&
        p.mean_adu + kTailSd * std::sqrt(p.variance_adu2) > ceiling - 0.5 * step) {
      lowest_top = k;
    }
  }
  *top_cut = lowest_top < n ? (*points)[lowest_top].bin_low_adu : kNaN;
  for (int k = 0; k < n; ++k) {
    PtcPoint& p = (*points)[k];
    auto exclude = [&p](const std::string& why) {
      if (p.used) p.excluded_because = why;
      p.used = false;
    };
    if (p.pixels < kMinSamplesPerPoint) {
      exclude(p.pixels == 0 ? "no samples" : "fewer than 30 samples");
    }
    if (k <= highest_floor || p.floor_fraction > kMaxClippedFraction) {
      exclude("over 0.1 % of its samples at the clipped black level");
    }
    if (k >= lowest_top) {
      exclude(k == lowest_top ? "its noise reaches the ADC's top or the saturation level"
                              : "above a level whose noise reaches the ADC's top or saturation");
    }
    if (p.mean_adu > full_scale_level) exclude("within 10 % of the ADC's full scale");
  }
  if (highest_floor < 0) {
    *floor_cut = kNaN;
  } else if (highest_floor + 1 < n) {
    *floor_cut = (*points)[highest_floor + 1].bin_low_adu;
  } else {
    *floor_cut = kInf;
  }
}

// Weighted least squares of var = sum_j c_j m^j (j < order) over the used points, weights
// dof / (2 model^2) iterated from the observed variances. Returns the coefficients and
// their covariance, unscaled, and chi2.
struct PolyFit {
  Eigen::VectorXd c;
  Eigen::MatrixXd cov;
  double chi2 = 0.0;
  int dof = 0;
  bool ok = false;
};

PolyFit FitPolynomial(const std::vector<PtcPoint>& points, int order) {
  PolyFit fit;
  std::vector<const PtcPoint*> used;
  for (const PtcPoint& p : points) {
    if (p.used) used.push_back(&p);
  }
  const int n = static_cast<int>(used.size());
  if (n < order) return fit;
  // The level origin at the mean level keeps the normal equations well conditioned; the
  // coefficients are transformed back below.
  double centre = 0.0;
  for (const PtcPoint* p : used) centre += p->mean_adu;
  centre /= n;
  std::vector<double> model(n);
  for (int i = 0; i < n; ++i) model[i] = used[i]->variance_adu2;
  Eigen::VectorXd c;
  Eigen::MatrixXd info;
  for (int iteration = 0; iteration < 6; ++iteration) {
    Eigen::MatrixXd X(n, order);
    Eigen::VectorXd y(n), w(n);
    for (int i = 0; i < n; ++i) {
      const double t = used[i]->mean_adu - centre;
      for (int j = 0; j < order; ++j) X(i, j) = std::pow(t, j);
      y(i) = used[i]->variance_adu2;
      // A model variance is floored at a tenth of the observed one (and above 0) so that a
      // transient negative model cannot give a point infinite weight.
      const double m = std::max({model[i], 0.1 * used[i]->variance_adu2, 1e-12});
      w(i) = used[i]->dof / (2.0 * m * m);
    }
    info = X.transpose() * w.asDiagonal() * X;
    Eigen::LDLT<Eigen::MatrixXd> ldlt(info);
    if (ldlt.info() != Eigen::Success) return fit;
    c = ldlt.solve(X.transpose() * w.asDiagonal() * y);
    for (int i = 0; i < n; ++i) model[i] = X.row(i).dot(c);
    fit.chi2 = 0.0;
    for (int i = 0; i < n; ++i) fit.chi2 += w(i) * (y(i) - model[i]) * (y(i) - model[i]);
  }
  Eigen::MatrixXd cov = info.inverse();
  if (!cov.allFinite()) return fit;
  // Back to the origin m = 0: coefficients are a linear map T of the centred ones.
  Eigen::MatrixXd T = Eigen::MatrixXd::Zero(order, order);
  for (int j = 0; j < order; ++j) {
    // (m - centre)^j = sum_k binom(j, k) m^k (-centre)^(j - k)
    double binom = 1.0;
    for (int k = 0; k <= j; ++k) {
      if (k > 0) binom = binom * (j - k + 1) / k;
      T(k, j) = binom * std::pow(-centre, j - k);
    }
  }
  fit.c = T * c;
  fit.cov = T * cov * T.transpose();
  fit.dof = n - order;
  fit.ok = fit.c.allFinite();
  return fit;
}

// The straight line through the used points, after dropping, one at a time and worst first,
// points further than kRejectPointSd of their own counting sd (var sqrt(2 / dof), from the
// model) from it: a bin where something did not cancel (a spot that moved between the
// frames of a pair, an arc's edge) is not noise, and one such point can turn the line over.
// At least 3 points are kept. The dropped points say so in excluded_because.

PolyFit FitLineRejecting(std::vector<PtcPoint>* points) {
  PolyFit line = FitPolynomial(*points, 2);
  while (line.ok) {
    int used = 0, worst = -1;
    double worst_z = 0.0;
    for (size_t k = 0; k < points->size(); ++k) {
      const PtcPoint& p = (*points)[k];
      if (!p.used) continue;
      ++used;
      const double model = line.c(0) + line.c(1) * p.mean_adu;
      const double sd = std::max(std::fabs(model), 1e-12) * std::sqrt(2.0 / p.dof);
      const double z = std::fabs(p.variance_adu2 - model) / sd;
      if (z > worst_z) worst_z = z, worst = static_cast<int>(k);
    }
    if (worst < 0 || worst_z <= kRejectPointSd || used <= 3) break;
    PtcPoint& p = (*points)[worst];
    p.used = false;
    p.excluded_because =
        Format("%.0f sd from the line through the others: not noise alone", worst_z);
    line = FitPolynomial(*points, 2);
  }
  return line;
}

// The pair illumination check: the weighted slope of the cells' mean difference against
// their level, and its sd. A pair taken under the same illumination has slope 0; frames whose
// light differs by a fraction f have slope ~f (d = f x (level - bias)).
std::pair<double, double> IlluminationChange(const std::vector<CellMean>& means,
                                             const std::vector<PtcPoint>& points) {
  double sw = 0, sx = 0, sy = 0, sxx = 0, sxy = 0;
  int n = 0;
  for (size_t k = 0; k < means.size(); ++k) {
    const CellMean& m = means[k];
    if (!points[k].used || !std::isfinite(m.diff) || !(m.diff_sd > 0.0)) continue;
    const double w = 1.0 / (m.diff_sd * m.diff_sd);
    sw += w, sx += w * m.level, sy += w * m.diff, sxx += w * m.level * m.level,
        sxy += w * m.level * m.diff;
    ++n;
  }
  const double den = sw * sxx - sx * sx;
  if (n < 3 || !(den > 0.0)) return {0.0, kInf};
  return {(sw * sxy - sx * sy) / den, std::sqrt(sw / den)};
}

}  // namespace

const char* PtcMethodName(PtcMethod method) {
  switch (method) {
    case PtcMethod::kPairs:
      return "pairs";
    case PtcMethod::kSingleFrame:
      return "single_frame";
    case PtcMethod::kAuto:
      break;
  }
  return "auto";
}

bool ParsePtcMethod(const std::string& text, PtcMethod* method) {
  for (PtcMethod m : {PtcMethod::kAuto, PtcMethod::kPairs, PtcMethod::kSingleFrame}) {
    if (text == PtcMethodName(m)) {
      *method = m;
      return true;
    }
  }
  return false;
}

bool PhotonTransferOptions::IsValid(std::string* error) const {
  if (num_bins < 3 || num_bins > 1000) {
    *error = "the number of level bins must be in [3, 1000] (got " + std::to_string(num_bins) + ")";
    return false;
  }
  if (min_samples_per_bin < 10) {
    *error = "a bin needs at least 10 samples (got " + std::to_string(min_samples_per_bin) + ")";
    return false;
  }
  return TransferFrameOptions::IsValid(error);
}

bool EstimatePhotonTransfer(const std::vector<FitsImage>& frames,
                            const std::vector<std::string>& names_in,
                            const PhotonTransferOptions& options, PhotonTransferResult* result,
                            std::string* error) {
  *result = PhotonTransferResult{};
  if (!options.IsValid(error)) return false;
  if (frames.empty()) {
    *error = "no frames to estimate a gain from";
    return false;
  }
  std::vector<std::string>& warnings = result->warnings;

  // Frames: exposure times, limits.
  TransferFrameSet set;
  if (!PrepareTransferFrames(frames, names_in, options, &set, &warnings, error)) return false;
  const std::vector<std::string>& names = set.names;
  const std::vector<Prepared>& prepared = set.frames;
  const std::vector<double>& exptimes = set.exptimes;
  const double rounding = set.rounding_adu2;
  result->rounding_adu2 = rounding;

  // A frame set without two different values has no noise to measure: say so plainly.
  {
    double lowest = kInf, highest = -kInf;
    for (const Prepared& p : prepared) {
      const Image& px = p.image->pixels;
      for (int y = p.region.y_begin; y < p.region.y_end; ++y) {
        for (int x = p.region.x_begin; x < p.region.x_end; ++x) {
          const double v = px(x, y);
          if (!std::isfinite(v)) continue;
          lowest = std::min(lowest, v);
          highest = std::max(highest, v);
        }
      }
    }
    if (!(lowest <= highest)) {
      *error = "no gain estimate: no finite pixel in the frame(s)";
      return false;
    }
    if (lowest == highest) {
      bool at_bottom = true;
      for (const FitsImage& f : frames) at_bottom &= lowest <= f.adc_min;
      *error = "no gain estimate: every pixel reads " + Num(lowest) + " ADU" +
               (at_bottom ? " (the ADC's bottom: a black level clipped with nothing above it)"
                          : " (a flat, noiseless frame has no noise to measure)");
      return false;
    }
  }

  // Pairs: frames of one illumination (photon_transfer_frames.h), two by two in input order.
  const std::vector<std::pair<size_t, size_t>> pairs =
      FindIlluminationPairs(set, options, &warnings);
  bool use_pairs = false;
  switch (options.method) {
    case PtcMethod::kPairs:
      if (pairs.empty()) {
        *error =
            "the pairs method needs two frames of the same size under the same illumination "
            "(exposure time, scene, WAVELEN, FOCUSPOS); none among " +
            std::to_string(frames.size()) + " frames";
        return false;
      }
      use_pairs = true;
      break;
    case PtcMethod::kSingleFrame:
      use_pairs = false;
      break;
    case PtcMethod::kAuto:
      use_pairs = !pairs.empty();
      break;
  }
  result->method = use_pairs ? "pairs" : "single_frame";

  std::vector<Source> sources;
  if (use_pairs) {
    for (size_t p = 0; p < pairs.size(); ++p) {
      const auto [i, j] = pairs[p];
      Source s = PairSamples(prepared[i], prepared[j]);
      s.label = names[i] + " - " + names[j];
      sources.push_back(std::move(s));
    }
    DescribePairs(pairs, &set, &warnings);
    result->pairs = static_cast<int>(pairs.size());
    result->frames_used = static_cast<int>(2 * pairs.size());
  } else {
    for (size_t i = 0; i < frames.size(); ++i) {
      Source s = SingleFrameSamples(prepared[i]);
      s.label = names[i];
      sources.push_back(std::move(s));
      set.info[i].role = "single frame";
    }
    result->frames_used = static_cast<int>(frames.size());
    if (options.method == PtcMethod::kAuto) {
      int unknown = 0;
      for (double t : exptimes) unknown += !std::isfinite(t);
      if (unknown > 0 && frames.size() > 1) {
        warnings.push_back(std::to_string(unknown) +
                           " frame(s) with no exposure time could not "
                           "be paired (give --exptime_s or a manifest)");
      }
    }
  }

  result->frames = set.info;

  // Clipping at the floor, for messages.
  bool any_clipped = false;
  double clip_level = kInf;
  double most_at_floor = 0.0;  // the largest fraction of a frame's pixels at its floor
  for (const PtcFrameInfo& info : result->frames) {
    if (info.floor_clipped) {
      any_clipped = true;
      clip_level = std::min(clip_level, info.floor_adu);
      most_at_floor = std::max(most_at_floor, info.floor_pixel_fraction);
    }
  }

  const std::vector<double> edges =
      BuildBins(sources, options.num_bins, options.min_samples_per_bin);
  std::string clip_note;
  if (any_clipped) clip_note = "the black level is clipped at " + Num(clip_level) + " ADU";
  if (edges.size() < 2) {
    *error =
        "no gain estimate: no usable levels (" +
        (any_clipped ? clip_note + ", and every pixel is at it or at the top"
                     : std::string("every pixel has the same value or is at the ADC's limits")) +
        ")";
    return false;
  }

  // The ADC's full scale, from the frames' ranges.
  double full_scale = kInf;
  for (const FitsImage& f : frames) {
    if (std::isfinite(f.adc_min) && std::isfinite(f.adc_max)) {
      full_scale = std::min(full_scale, f.adc_min + kFullScaleFraction * (f.adc_max - f.adc_min));
    }
  }

  double ceiling = kInf;
  for (const PtcFrameInfo& info : result->frames) ceiling = std::min(ceiling, info.ceiling_adu);
  const double step = std::sqrt(12.0 * rounding);

  // First selection, before any noise model: for pairs the neighbours' t statistic, for
  // single frames each bin's median ring variance as the noise reference (most blocks of a
  // level are smooth; the median of chi2_29 / 29 is 0.977). Neither needs the limit rules,
  // so a frame whose levels are mostly excluded is still selected.
  std::vector<std::vector<uint8_t>> selected;
  for (const Source& s : sources) selected.emplace_back(s.samples.size(), 1);
  if (use_pairs) {
    // Pairs: the first selection needs no noise model. It asks whether the 8 neighbours'
    // differences are consistent with a common mean of zero: t = mean / (sd / sqrt(8)), a
    // Student t with 7 dof under noise alone (|t| > 5 in 0.16 % of cases). Lobes left by a
    // spot that moved are coherent and fail it at any level.
    for (size_t si = 0; si < sources.size(); ++si) {
      for (size_t i = 0; i < sources[si].samples.size(); ++i) {
        const Sample& x = sources[si].samples[i];
        const double t = std::fabs(x.structure) /
                         std::max(static_cast<double>(x.structure_sd) / std::sqrt(8.0), 1e-9);
        selected[si][i] = x.structure == 0.0f || t <= kPairFirstT;
      }
    }
  } else {
    const int nbins = static_cast<int>(edges.size()) - 1;
    std::vector<std::vector<float>> structures(nbins);
    for (const Source& src : sources) {
      for (const Sample& x : src.samples) {
        if (!(x.flags & kTouchesCeiling))
          structures[BinOf(edges, x.bin_level)].push_back(x.structure);
      }
    }
    std::vector<double> reference(nbins, kInf);
    for (int k = 0; k < nbins; ++k) {
      std::vector<float>& v = structures[k];
      if (v.empty()) continue;
      std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
      reference[k] = v[v.size() / 2] / 0.977;
    }
    for (size_t si = 0; si < sources.size(); ++si) {
      for (size_t i = 0; i < sources[si].samples.size(); ++i) {
        const Sample& x = sources[si].samples[i];
        selected[si][i] = x.structure <= kSmoothFactor * reference[BinOf(edges, x.bin_level)];
      }
    }
  }
  // Rounds: accumulate, fit, and take the fit as the noise model of the next round (outlier
  // clipping at each sample's level, effective dof, and for single frames the smoothness
  // selection), until the model and the selection stop changing.
  Accumulated acc;
  PolyFit line;
  NoiseModel model;
  double floor_cut = kNaN, top_cut = kNaN;
  for (int round = 0; round < kMaxSelectionRounds; ++round) {
    acc = Accumulate(sources, edges, selected, model);
    ApplyRules(&acc.points, ceiling, step, full_scale, &floor_cut, &top_cut);
    line = FitLineRejecting(&acc.points);
    if (!line.ok || round + 1 == kMaxSelectionRounds) break;
    // The line serves as a noise model only where it can be one: positive across the binned
    // levels (a fit that went negative would select nothing).
    if (!(line.c(0) + line.c(1) * edges.front() > 0.0) ||
        !(line.c(0) + line.c(1) * edges.back() > 0.0)) {
      break;
    }
    NoiseModel next;
    next.ok = true;
    next.a = line.c(0);
    next.b = line.c(1);
    next.floor = std::max(1e-6, rounding);
    bool changed = !model.ok || std::fabs(next.b - model.b) > 1e-6 * std::fabs(model.b) ||
                   std::fabs(next.a - model.a) > 1e-6 * std::max(1.0, std::fabs(model.a));
    model = next;
    for (size_t si = 0; si < sources.size(); ++si) {
      const std::vector<CellMean>& cell = acc.cell_means[si];
      for (size_t i = 0; i < sources[si].samples.size(); ++i) {
        const Sample& x = sources[si].samples[i];
        uint8_t keep = 0;
        if (use_pairs) {
          // The neighbours' mean difference under noise alone: the cell's mean, with sd
          // sqrt(2 v / 8) at the neighbours' level.
          const int k = BinOf(edges, x.bin_level);
          const double centre = std::isfinite(cell[k].diff) ? cell[k].diff : 0.0;
          keep = std::fabs(x.structure - centre) <=
                 kPairStructureSd * std::sqrt(2.0 * model.At(x.bin_level) / 8.0);
        } else {
          keep = x.structure <= kSmoothFactor * model.At(x.bin_level);
        }
        changed |= keep != selected[si][i];
        selected[si][i] = keep;
      }
    }
    if (!changed) break;
  }
  if (!use_pairs) {
    long long kept = 0, total = 0;
    for (size_t si = 0; si < sources.size(); ++si) {
      for (size_t i = 0; i < sources[si].samples.size(); ++i) {
        if (sources[si].samples[i].flags & kTouchesCeiling) continue;
        ++total;
        kept += selected[si][i];
      }
    }
    if (total > 0 && kept < 0.5 * total) {
      warnings.push_back(
          Format("only %.0f %% of the frame(s)' 2 x 2 blocks are smooth enough to use",
                 100.0 * kept / total));
    }
  }

  if (any_clipped) {
    std::string text = clip_note;
    if (std::isfinite(floor_cut)) {
      text += ": levels below " + Num(floor_cut) + " ADU excluded";
    } else if (floor_cut == kInf) {
      text += ": every level is affected";
    }
    warnings.push_back(text);
  }
  if (std::isfinite(top_cut)) {
    warnings.push_back("levels above " + Num(top_cut) + " ADU excluded: their noise reaches " +
                       (std::isfinite(ceiling) ? Num(ceiling) + " ADU, " : std::string()) +
                       "the ADC's top or the saturation level");
  }
  result->points = acc.points;
  int used = 0;
  double lo = kInf, hi = -kInf;
  bool any_noise = false;
  bool within_rounding = true;
  for (const PtcPoint& p : acc.points) {
    if (!p.used) continue;
    ++used;
    lo = std::min(lo, p.mean_adu);
    hi = std::max(hi, p.mean_adu);
    any_noise |= p.variance_adu2 > 1e-10;
    // Rounding a noiseless smooth image gives dd mostly in {-1, 0, 1}: var(dd) / 4 <= 1/4 ADU^2
    // = 3 q. A variance that never exceeds this may be rounding alone.
    within_rounding &= p.variance_adu2 <= 3.0 * rounding + 1e-10;
  }
  result->points_used = used;
  auto why_few = [&]() {
    std::string why = std::to_string(used) + " usable";
    if (any_clipped) {
      why += "; " + clip_note;
      if (std::isfinite(floor_cut)) why += ": levels below " + Num(floor_cut) + " ADU excluded";
    }
    if (std::isfinite(top_cut)) why += "; levels above " + Num(top_cut) + " ADU excluded";
    return why;
  };
  if (used < 3) {
    *error = "no gain estimate: fewer than 3 usable level bins (" + why_few() + ")";
    return false;
  }
  if (!any_noise) {
    *error = "no gain estimate: the variance is 0 at every level (a noiseless frame?)";
    return false;
  }
  if (!line.ok) {
    *error = "no gain estimate: the transfer-curve fit failed (" + why_few() + ")";
    return false;
  }
  const double scale = line.dof > 0 ? std::max(1.0, line.chi2 / line.dof) : 1.0;
  const Eigen::Matrix2d cov = line.cov * scale;
  const double a = line.c(0), b = line.c(1);
  const double sd_b = std::sqrt(cov(1, 1));
  result->chi2 = line.chi2;
  result->dof = line.dof;
  result->intercept_adu2 = a;
  result->intercept_sd_adu2 = std::sqrt(cov(0, 0));
  result->slope_per_adu = b;
  result->slope_sd_per_adu = sd_b;
  result->min_level_adu = lo;
  result->max_level_adu = hi;
  if (!(b > StudentQuantile3Sd(line.dof) * sd_b)) {
    *error =
        "no gain estimate: the variance does not grow significantly with the level "
        "(slope " +
        Format("%.3g", b) + " +- " + Format("%.2g", sd_b) + " per ADU from " +
        std::to_string(used) + " points over " + Num(lo) + " to " + Num(hi) + " ADU" +
        (within_rounding && rounding > 0.0
             ? ": no variance beyond the ADC's rounding, as in a noiseless frame)"
         : hi - lo < 10.0 * std::sqrt(std::max(a + b * hi, rounding))
             ? ": the levels span a few noise sds only, as in a flat field; frames with a "
               "range of levels are needed)"
             : ")");
    return false;
  }
  // The points' sd from the fitted model.
  for (PtcPoint& p : result->points) {
    if (p.dof > 0 && std::isfinite(p.mean_adu)) {
      p.variance_sd_adu2 = std::max(a + b * p.mean_adu, 0.0) * std::sqrt(2.0 / p.dof);
    }
  }
  const double g = 1.0 / b;
  result->gain_e_per_adu = g;
  result->gain_sd_e_per_adu = sd_b * g * g;
  if (result->gain_sd_e_per_adu > kUncertainGain * g) {
    warnings.push_back(Format("the gain is uncertain to %.0f %%: the points span only ",
                              100.0 * result->gain_sd_e_per_adu / g) +
                       Num(lo) + " to " + Num(hi) + " ADU");
  }
  if (std::sqrt(scale) >= 1.1) {
    warnings.push_back(
        Format("the points scatter %.2g x more than their counting errors "
               "(chi2/dof); the sds are scaled up accordingly",
               std::sqrt(scale)));
  }
  if (used >= 4) {
    PolyFit quad = FitPolynomial(result->points, 3);
    if (quad.ok && quad.dof > 0) {
      const double qscale = std::max(1.0, quad.chi2 / quad.dof);
      const double t = quad.c(2) / std::sqrt(quad.cov(2, 2) * qscale);
      if (std::fabs(t) > kCurvatureSignificance) {
        warnings.push_back(
            Format("the transfer curve bends (quadratic term at %.1f sd): "
                   "nonlinearity or fixed pattern; the gain is the mean slope "
                   "over the levels used",
                   t));
      }
    }
  }

  // Pairs whose illumination differs.
  if (use_pairs) {
    for (size_t p = 0; p < sources.size(); ++p) {
      const auto [change, change_sd] = IlluminationChange(acc.cell_means[p], result->points);
      if (std::fabs(change) > kMaxPairIlluminationChange && std::fabs(change) > 3.0 * change_sd) {
        warnings.push_back("pair " + std::to_string(p + 1) + " (" + sources[p].label +
                           "): the illumination differs by " + Format("%.0f %%", 100 * change) +
                           " between its frames (really the same exposure time?)");
      }
    }
  }

  // Bias and read noise. var = a + m b with a = q - bias b + (RN b)^2, so
  // RN^2 [e-^2] = (a - q + bias b) / b^2.
  const BiasEstimate bias = ResolveTransferBias(set, options, &warnings);
  result->bias_adu = bias.value;
  result->bias_sd_adu = bias.sd;
  result->bias_source = bias.source;
  if (std::isfinite(bias.value)) {
    const double r = a - rounding + bias.value * b;
    const double rn2 = r / (b * b);
    const double da = 1.0 / (b * b);
    const double db = bias.value / (b * b) - 2.0 * r / (b * b * b);
    const double dbias = 1.0 / b;
    const double var = da * da * cov(0, 0) + 2.0 * da * db * cov(0, 1) + db * db * cov(1, 1) +
                       dbias * dbias * bias.sd * bias.sd;
    const double sd = std::sqrt(std::max(var, 0.0));
    if (rn2 > kReadNoiseSignificance * sd) {
      result->read_noise_e = std::sqrt(rn2);
      result->read_noise_sd_e = sd / (2.0 * result->read_noise_e);
    } else {
      result->read_noise_upper_e = std::sqrt(std::max(0.0, rn2 + kReadNoiseSignificance * sd));
      warnings.push_back("read noise not significant: RN^2 = " + Format("%.3g", rn2) + " +- " +
                         Format("%.2g", sd) + " e-^2, RN < " +
                         Format("%.3g", result->read_noise_upper_e) + " e- (2 sd)");
    }
  } else {
    std::string text =
        "no bias level known (give one, or BIASLVL, a bias section BIASSEC or zero-second "
        "frames): the intercept mixes bias and read noise, so no read noise";
    if (any_clipped && most_at_floor >= 0.5) {
      // At least half of a frame's pixels read the clipped value. Dark pixels read it at
      // least as often as lit ones, so at least half of them do: their median reading,
      // round(bias), is the clipped value, and the bias is at most half a step above it.
      // RN^2 = (a - q + bias b) / b^2 is then bounded from above.
      const double bias_max = clip_level + 0.5 * (step > 0.0 ? step : 1.0);
      const double rn2_max = (a - rounding + bias_max * b) / (b * b);
      const double da = 1.0 / (b * b);
      const double db = bias_max / (b * b) - 2.0 * (a - rounding + bias_max * b) / (b * b * b);
      const double sd = std::sqrt(
          std::max(0.0, da * da * cov(0, 0) + 2.0 * da * db * cov(0, 1) + db * db * cov(1, 1)));
      const double upper = rn2_max + kReadNoiseSignificance * sd;
      if (upper > 0.0) {
        result->read_noise_upper_e = std::sqrt(upper);
        text += Format(
                    "; with the bias at most %.3g ADU (most pixels read the clipped "
                    "value), RN < ",
                    bias_max) +
                Format("%.3g e- (2 sd)", result->read_noise_upper_e);
      } else {
        text += "; the intercept is too low for a bias at or below the clipped level";
      }
    }
    warnings.push_back(text);
  }
  return true;
}

bool EstimatePhotonTransferFromFiles(const std::vector<std::string>& paths,
                                     const PhotonTransferOptions& options,
                                     PhotonTransferResult* result, std::string* error) {
  std::vector<FitsImage> frames;
  return ReadTransferFrames(paths, &frames, error) &&
         EstimatePhotonTransfer(frames, paths, options, result, error);
}

using internal::JsonNumber;

nlohmann::json PhotonTransferJson(const PhotonTransferResult& r) {
  nlohmann::json points = nlohmann::json::array();
  for (const PtcPoint& p : r.points) {
    nlohmann::json j = {{"mean_adu", JsonNumber(p.mean_adu)},
                        {"variance_adu2", JsonNumber(p.variance_adu2)},
                        {"variance_sd_adu2", JsonNumber(p.variance_sd_adu2)},
                        {"pixels", p.pixels},
                        {"bin_low_adu", JsonNumber(p.bin_low_adu)},
                        {"bin_high_adu", JsonNumber(p.bin_high_adu)},
                        {"floor_fraction", p.floor_fraction},
                        {"ceiling_fraction", p.ceiling_fraction},
                        {"used", p.used}};
    if (!p.used) j["excluded_because"] = p.excluded_because;
    points.push_back(j);
  }
  const nlohmann::json frames = TransferFramesJson(r.frames);
  return {{"method", r.method},
          {"gain_e_per_adu", JsonNumber(r.gain_e_per_adu)},
          {"gain_sd_e_per_adu", JsonNumber(r.gain_sd_e_per_adu)},
          {"read_noise_e", JsonNumber(r.read_noise_e)},
          {"read_noise_sd_e", JsonNumber(r.read_noise_sd_e)},
          {"read_noise_upper_e", JsonNumber(r.read_noise_upper_e)},
          {"bias_adu", JsonNumber(r.bias_adu)},
          {"bias_sd_adu", JsonNumber(r.bias_sd_adu)},
          {"bias_source", r.bias_source},
          {"fit",
           {{"model", "variance_adu2 = intercept_adu2 + mean_adu / gain_e_per_adu"},
            {"intercept_adu2", JsonNumber(r.intercept_adu2)},
            {"intercept_sd_adu2", JsonNumber(r.intercept_sd_adu2)},
            {"slope_per_adu", JsonNumber(r.slope_per_adu)},
            {"slope_sd_per_adu", JsonNumber(r.slope_sd_per_adu)},
            {"rounding_adu2", r.rounding_adu2},
            {"chi2", r.chi2},
            {"dof", r.dof},
            {"points_used", r.points_used},
            {"min_level_adu", JsonNumber(r.min_level_adu)},
            {"max_level_adu", JsonNumber(r.max_level_adu)}}},
          {"pairs", r.pairs},
          {"frames_used", r.frames_used},
          {"frames", frames},
          {"points", points},
          {"warnings", r.warnings}};
}

std::string PhotonTransferCsv(const PhotonTransferResult& r) {
  std::ostringstream csv;
  csv << "mean_adu,variance_adu2,variance_sd_adu2,pixels,used\n";
  char line[160];
  for (const PtcPoint& p : r.points) {
    if (!std::isfinite(p.mean_adu) || !std::isfinite(p.variance_adu2)) continue;
    std::snprintf(line, sizeof(line), "%.10g,%.10g,%.6g,%lld,%d\n", p.mean_adu, p.variance_adu2,
                  p.variance_sd_adu2, p.pixels, p.used ? 1 : 0);
    csv << line;
  }
  return csv.str();
}

}  // namespace ccdpsf
