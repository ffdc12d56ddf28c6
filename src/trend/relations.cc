#include "ccdpsf/trend/relations.h"

#include <algorithm>
#include <array>
#include <cstdio>
#include <initializer_list>
#include <limits>
#include <random>

#include "ccdpsf/random.h"

namespace ccdpsf::trend {
namespace {

using nlohmann::json;

// Central 68.27 % interval: 1 sigma of a Gaussian (the same bounds as fit.json).
constexpr double kLo68 = 0.158655;
constexpr double kHi68 = 0.841345;

// Percentiles at increasing qs by linear interpolation between order statistics (the
// same numbers as sorting, by selection: O(n) per percentile). Reorders v; NaN if empty.
void SelectPercentiles(std::vector<double>& v, std::initializer_list<double> qs, double* out) {
  const size_t n = v.size();
  size_t start = 0;
  for (double q : qs) {
    if (n == 0) {
      *out++ = NAN;
      continue;
    }
    const double pos = q * static_cast<double>(n - 1);
    const size_t lo = static_cast<size_t>(std::floor(pos));
    // Everything before `start` is <= everything from it on, so select within [start, n).
    std::nth_element(v.begin() + start, v.begin() + lo, v.end());
    const double v_lo = v[lo];
    const double v_hi = lo + 1 < n ? *std::min_element(v.begin() + lo + 1, v.end()) : v_lo;
    *out++ = v_lo + (pos - static_cast<double>(lo)) * (v_hi - v_lo);
    start = lo;
  }
}

// Sample sd (n - 1 denominator) of finite values; NaN for fewer than 2.
double SampleSd(const std::vector<double>& v) {
  if (v.size() < 2) return NAN;
  double mean = 0.0;
  for (double x : v) mean += x;
  mean /= static_cast<double>(v.size());
  double ss = 0.0;
  for (double x : v) ss += (x - mean) * (x - mean);
  return std::sqrt(ss / static_cast<double>(v.size() - 1));
}

double Median(std::vector<double> v) {
  double m;
  SelectPercentiles(v, {0.5}, &m);
  return m;
}

std::string Num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.3g", v);
  return buf;
}

json NullIfNan(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

// Regularized upper incomplete gamma Q(a, x) for a > 0, x >= 0: the series for P when
// x < a + 1, else the continued fraction for Q (modified Lentz), both to ~1e-15.
double RegularizedGammaQ(double a, double x) {
  if (x <= 0.0) return 1.0;
  const double log_prefactor = -x + a * std::log(x) - std::lgamma(a);
  if (x < a + 1.0) {
    double ap = a, term = 1.0 / a, sum = term;
    for (int n = 0; n < 10000; ++n) {
      ap += 1.0;
      term *= x / ap;
      sum += term;
      if (std::fabs(term) < std::fabs(sum) * 1e-16) break;
    }
    return std::max(0.0, 1.0 - sum * std::exp(log_prefactor));
  }
  constexpr double kTiny = 1e-300;
  double b = x + 1.0 - a, c = 1.0 / kTiny, d = 1.0 / b, h = d;
  for (int i = 1; i < 10000; ++i) {
    const double an = -i * (i - a);
    b += 2.0;
    d = an * d + b;
    if (std::fabs(d) < kTiny) d = kTiny;
    c = b + an / c;
    if (std::fabs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    const double delta = d * c;
    h *= delta;
    if (std::fabs(delta - 1.0) < 1e-16) break;
  }
  return std::exp(log_prefactor) * h;
}

// A point ready for fitting, in the fitted space y (log X for the power law).
struct UsablePoint {
  std::string label;
  double x = NAN;
  double u = NAN;                 // transformed abscissa
  std::vector<double> y_draws;    // empty for a Gaussian point
  std::vector<double> prior_y;    // prior draws in y (empty: flat prior)
  double y_mean = NAN, y_sd = NAN;  // Gaussian point's parameters in y
  double y_center = NAN;          // median in y
  double s = NAN;                 // sd in y: the weight is 1 / s^2
  Estimate value;                 // of X
  bool gaussian = false;
};

// Why the point cannot be used (empty: usable, *out filled).
std::string PreparePoint(RelationKind kind, const RelationPoint& p, double pivot,
                         UsablePoint* out) {
  const bool power = kind == RelationKind::kPowerLaw;
  if (!p.missing_reason.empty()) return p.missing_reason;
  if (!std::isfinite(p.abscissa)) return "abscissa is not finite";
  if (power && p.abscissa <= 0.0) {
    return "abscissa " + Num(p.abscissa) + " <= 0: a power law is fitted in log(x)";
  }
  out->label = p.label;
  out->x = p.abscissa;
  out->u = power ? std::log(p.abscissa / pivot) : (p.abscissa - pivot) / pivot;
  if (!p.draws.empty()) {
    std::vector<double> finite;
    finite.reserve(p.draws.size());
    for (double d : p.draws) {
      if (std::isfinite(d)) finite.push_back(d);
    }
    if (finite.size() < 2) {
      return std::to_string(finite.size()) + " finite posterior draws (need at least 2)";
    }
    if (power) {
      const size_t non_positive = static_cast<size_t>(
          std::count_if(finite.begin(), finite.end(), [](double d) { return d <= 0.0; }));
      if (non_positive > 0) {
        return std::to_string(non_positive) + " of " + std::to_string(finite.size()) +
               " draws are <= 0: a power law is fitted in log(X)";
      }
    }
    out->y_draws = finite;
    if (power) {
      for (double& y : out->y_draws) y = std::log(y);
    }
    // Prior draws outside the fitted space's domain (X <= 0 for a power law) carry no
    // density where the posterior lives: dropped.
    for (double d : p.prior_draws) {
      if (!std::isfinite(d) || (power && d <= 0.0)) continue;
      out->prior_y.push_back(power ? std::log(d) : d);
    }
    out->s = SampleSd(out->y_draws);
    if (!(out->s > 0.0) || !std::isfinite(out->s)) {
      return "posterior draws have no spread: the weight 1/sd^2 is undefined";
    }
    out->y_center = Median(out->y_draws);
    out->value = SummarizeDraws(std::move(finite));
    return "";
  }
  if (!std::isfinite(p.median) || !std::isfinite(p.sd) || !(p.sd > 0.0)) {
    return "no posterior draws and no finite median with sd > 0";
  }
  if (power && p.median <= 0.0) {
    return "median " + Num(p.median) + " <= 0: a power law is fitted in log(X)";
  }
  out->gaussian = true;
  // In log space the Gaussian N(m, s^2) becomes N(log m, (s/m)^2) to first order.
  out->y_mean = power ? std::log(p.median) : p.median;
  out->y_sd = power ? p.sd / p.median : p.sd;
  out->y_center = out->y_mean;
  out->s = out->y_sd;
  out->value.median = p.median;
  out->value.lo68 = p.median - p.sd;
  out->value.hi68 = p.median + p.sd;
  out->value.sd = p.sd;
  return "";
}

// Minimises f over R^3 by Nelder-Mead from x0 with initial steps `step` (deterministic).
template <typename F>
std::array<double, 3> NelderMead3(const F& f, std::array<double, 3> x0, std::array<double, 3> step,
                                  int max_evaluations) {
  using P = std::array<double, 3>;
  std::array<P, 4> x;
  std::array<double, 4> fx;
  x[0] = x0;
  for (int i = 0; i < 3; ++i) {
    x[i + 1] = x0;
    x[i + 1][i] += step[i];
  }
  for (int i = 0; i < 4; ++i) fx[i] = f(x[i]);
  int evaluations = 4;
  auto along = [](const P& c, const P& w, double t) {
    P out;
    for (int k = 0; k < 3; ++k) out[k] = c[k] + t * (w[k] - c[k]);
    return out;
  };
  while (evaluations < max_evaluations) {
    std::array<int, 4> order = {0, 1, 2, 3};
    std::sort(order.begin(), order.end(), [&](int i, int j) { return fx[i] < fx[j]; });
    std::array<P, 4> xs;
    std::array<double, 4> fs;
    for (int i = 0; i < 4; ++i) {
      xs[i] = x[order[i]];
      fs[i] = fx[order[i]];
    }
    x = xs;
    fx = fs;
    if (std::fabs(fx[3] - fx[0]) < 1e-12 * (1.0 + std::fabs(fx[0]))) break;
    P c = {0, 0, 0};
    for (int i = 0; i < 3; ++i) {
      for (int k = 0; k < 3; ++k) c[k] += x[i][k] / 3.0;
    }
    const P r = along(c, x[3], -1.0);
    const double fr = f(r);
    ++evaluations;
    if (fr < fx[0]) {
      const P e = along(c, x[3], -2.0);
      const double fe = f(e);
      ++evaluations;
      if (fe < fr) {
        x[3] = e;
        fx[3] = fe;
      } else {
        x[3] = r;
        fx[3] = fr;
      }
    } else if (fr < fx[2]) {
      x[3] = r;
      fx[3] = fr;
    } else {
      const P k = fr < fx[3] ? along(c, r, 0.5) : along(c, x[3], 0.5);
      const double fk = f(k);
      ++evaluations;
      if (fk < std::min(fr, fx[3])) {
        x[3] = k;
        fx[3] = fk;
      } else {
        for (int i = 1; i < 4; ++i) {
          x[i] = along(x[0], x[i], 0.5);
          fx[i] = f(x[i]);
          ++evaluations;
        }
      }
    }
  }
  int best = 0;
  for (int i = 1; i < 4; ++i) {
    if (fx[i] < fx[best]) best = i;
  }
  return x[best];
}

// log L_i(y) of one point, up to a constant: a split normal (two half-Gaussians of widths
// s_lo below the mode m and s_hi above it; relations.h, "Method"). For a Gaussian point
// s_lo = s_hi = its sd. For draws, (m, s_lo, s_hi) maximise the likelihood of the
// posterior draws under the model L(y) p_prior(y) / Z, Z = integral of L p_prior: with no
// prior draws p_prior is flat and Z = sqrt(pi/2) (s_lo + s_hi); else p_prior is the
// histogram of the prior draws (200 bins over their range) and Z sums erf integrals of L
// over the bins. No density of the posterior is estimated, so the fit has the precision of
// the draws' moments: for Gaussian draws (m, s) are their mean and sd to O(1/sqrt(n)).
class PointLikelihood {
 public:
  static PointLikelihood Gaussian(double mean, double sd) {
    PointLikelihood l;
    l.m_ = mean;
    l.s_lo_ = l.s_hi_ = sd;
    return l;
  }

  static PointLikelihood FromDraws(const std::vector<double>& y, const std::vector<double>& prior) {
    const double n = static_cast<double>(y.size());
    const double sd = SampleSd(y);
    double mean = 0.0;
    for (double v : y) mean += v / n;
    std::vector<double> bin_density, edges;
    if (!prior.empty()) {
      const auto [lo, hi] = std::minmax_element(prior.begin(), prior.end());
      if (*hi > *lo) {
        constexpr int kBins = 200;
        edges.resize(kBins + 1);
        for (int b = 0; b <= kBins; ++b) edges[b] = *lo + (*hi - *lo) * b / kBins;
        bin_density.assign(kBins, 0.0);
        const double width = (*hi - *lo) / kBins;
        for (double v : prior) {
          const int b = std::min(kBins - 1, static_cast<int>((v - *lo) / width));
          bin_density[b] += 1.0 / (static_cast<double>(prior.size()) * width);
        }
      }
    }
    const bool divide = !bin_density.empty();
    // Widths may not exceed 100 x the scale of everything seen (flat is flat by then).
    const double scale = divide ? std::max(sd, edges.back() - edges.front()) : sd;
    const double log_s_min = std::log(1e-3 * sd), log_s_max = std::log(100.0 * scale);
    auto objective = [&](const std::array<double, 3>& t) {
      if (!(t[1] >= log_s_min && t[1] <= log_s_max && t[2] >= log_s_min && t[2] <= log_s_max)) {
        return static_cast<double>(INFINITY);
      }
      PointLikelihood l;
      l.m_ = t[0];
      l.s_lo_ = std::exp(t[1]);
      l.s_hi_ = std::exp(t[2]);
      double sum = 0.0;
      for (double v : y) sum += l(v);
      double z = 0.0;
      if (divide) {
        for (size_t b = 0; b + 1 < edges.size(); ++b) {
          if (bin_density[b] > 0.0) z += bin_density[b] * l.Integral(edges[b], edges[b + 1]);
        }
      } else {
        z = std::sqrt(M_PI / 2.0) * (l.s_lo_ + l.s_hi_);
      }
      if (!(z > 0.0)) return static_cast<double>(INFINITY);
      return -sum / n + std::log(z);
    };
    const std::array<double, 3> t = NelderMead3(
        objective, {mean, std::log(sd), std::log(sd)}, {0.3 * sd, 0.3, 0.3}, 2000);
    PointLikelihood l;
    l.m_ = t[0];
    l.s_lo_ = std::exp(t[1]);
    l.s_hi_ = std::exp(t[2]);
    l.prior_divided_ = divide;
    return l;
  }

  double operator()(double y) const {
    const double z = (y - m_) / (y < m_ ? s_lo_ : s_hi_);
    return -0.5 * z * z;
  }

  // Integral of exp(log L) over [a, b].
  double Integral(double a, double b) const {
    const double root2 = std::sqrt(2.0), c = std::sqrt(M_PI / 2.0);
    double sum = 0.0;
    if (a < m_) {
      const double top = std::min(b, m_);
      sum += c * s_lo_ * (std::erf((top - m_) / (root2 * s_lo_)) - std::erf((a - m_) / (root2 * s_lo_)));
    }
    if (b > m_) {
      const double bottom = std::max(a, m_);
      sum += c * s_hi_ * (std::erf((b - m_) / (root2 * s_hi_)) - std::erf((bottom - m_) / (root2 * s_hi_)));
    }
    return sum;
  }

  bool prior_divided() const { return prior_divided_; }

 private:
  bool prior_divided_ = false;
  double m_ = NAN, s_lo_ = NAN, s_hi_ = NAN;
};

// A 2x2 symmetric matrix [a b; b c] and its lower Cholesky factor [l00 0; l10 l11].
struct Sym2 {
  double a = 0, b = 0, c = 0;
};
struct Chol2 {
  double l00 = 0, l10 = 0, l11 = 0;
};
bool Cholesky(const Sym2& m, Chol2* out) {
  if (!(m.a > 0.0)) return false;
  out->l00 = std::sqrt(m.a);
  out->l10 = m.b / out->l00;
  const double d = m.c - out->l10 * out->l10;
  if (!(d > 0.0) || !std::isfinite(d)) return false;
  out->l11 = std::sqrt(d);
  return true;
}

// The (c0, c1) posterior on nodes c = centre + L z, z on a square grid of g x g nodes over
// [-z_max, z_max]^2; weights normalised to sum 1.
struct GridPosterior {
  double centre[2] = {0, 0};
  Chol2 l;
  int g = 0;
  double z_max = 0, dz = 0;
  std::vector<double> c0, c1, w;
  double border_weight = 0;  // weight on the outermost ring of nodes
};

GridPosterior EvaluateGrid(const std::vector<UsablePoint>& pts,
                           const std::vector<PointLikelihood>& like, const double centre[2],
                           const Chol2& l, int g, double z_max) {
  GridPosterior out;
  out.centre[0] = centre[0];
  out.centre[1] = centre[1];
  out.l = l;
  out.g = g;
  out.z_max = z_max;
  out.dz = 2.0 * z_max / (g - 1);
  const size_t nodes = static_cast<size_t>(g) * g;
  out.c0.resize(nodes);
  out.c1.resize(nodes);
  out.w.resize(nodes);
  double best = -INFINITY;
  for (int a = 0; a < g; ++a) {
    for (int b = 0; b < g; ++b) {
      const double z0 = -z_max + a * out.dz, z1 = -z_max + b * out.dz;
      const double c0 = centre[0] + l.l00 * z0;
      const double c1 = centre[1] + l.l10 * z0 + l.l11 * z1;
      double log_p = 0.0;
      for (size_t i = 0; i < pts.size(); ++i) log_p += like[i](c0 + c1 * pts[i].u);
      const size_t k = static_cast<size_t>(a) * g + b;
      out.c0[k] = c0;
      out.c1[k] = c1;
      out.w[k] = log_p;
      best = std::max(best, log_p);
    }
  }
  double total = 0.0;
  for (double& w : out.w) {
    w = std::exp(w - best);
    total += w;
  }
  for (int a = 0; a < g; ++a) {
    for (int b = 0; b < g; ++b) {
      const size_t k = static_cast<size_t>(a) * g + b;
      out.w[k] /= total;
      if (a == 0 || b == 0 || a == g - 1 || b == g - 1) out.border_weight += out.w[k];
    }
  }
  return out;
}

// Weighted mean and covariance of the nodes (plus a cell's own spread, so that a posterior
// narrower than one cell still gives a positive definite matrix).
void GridMoments(const GridPosterior& grid, double mean[2], Sym2* cov) {
  mean[0] = mean[1] = 0.0;
  for (size_t k = 0; k < grid.w.size(); ++k) {
    mean[0] += grid.w[k] * grid.c0[k];
    mean[1] += grid.w[k] * grid.c1[k];
  }
  Sym2 m;
  for (size_t k = 0; k < grid.w.size(); ++k) {
    const double d0 = grid.c0[k] - mean[0], d1 = grid.c1[k] - mean[1];
    m.a += grid.w[k] * d0 * d0;
    m.b += grid.w[k] * d0 * d1;
    m.c += grid.w[k] * d1 * d1;
  }
  // A uniform cell of side dz in z has variance dz^2 / 12 per axis: L (dz^2/12) L^T.
  const double v = grid.dz * grid.dz / 12.0;
  const Chol2& l = grid.l;
  m.a += v * l.l00 * l.l00;
  m.b += v * l.l00 * l.l10;
  m.c += v * (l.l10 * l.l10 + l.l11 * l.l11);
  *cov = m;
}

// The posterior grid, iterated from the weighted least-squares start until its moments
// settle (relations.h, "Method"). False if no usable grid could be made.
bool SolveGrid(const std::vector<UsablePoint>& pts, const std::vector<PointLikelihood>& like,
               const double wls_centre[2], const Sym2& wls_cov, GridPosterior* out) {
  double centre[2] = {wls_centre[0], wls_centre[1]};
  // Wide first look: the least-squares sds can be far off when points are not Gaussian.
  Sym2 cov{9.0 * wls_cov.a, 9.0 * wls_cov.b, 9.0 * wls_cov.c};
  for (int pass = 0; pass < 8; ++pass) {
    Chol2 l;
    if (!Cholesky(cov, &l)) return false;
    GridPosterior grid = EvaluateGrid(pts, like, centre, l, 101, 6.0);
    double mean[2];
    Sym2 next;
    GridMoments(grid, mean, &next);
    // Settled: the centre moved < 0.05 sd and the sds changed < 5 %, nothing at the border.
    const double move = std::hypot((mean[0] - centre[0]) / std::sqrt(next.a),
                                   (mean[1] - centre[1]) / std::sqrt(next.c));
    const bool settled = pass > 0 && grid.border_weight < 1e-6 && move < 0.05 &&
                         std::fabs(std::sqrt(next.a / cov.a) - 1.0) < 0.05 &&
                         std::fabs(std::sqrt(next.c / cov.c) - 1.0) < 0.05;
    centre[0] = mean[0];
    centre[1] = mean[1];
    // Weight at the border: the posterior reaches beyond the grid; look wider next time.
    cov = grid.border_weight > 1e-6 ? Sym2{4.0 * next.a, 4.0 * next.b, 4.0 * next.c} : next;
    if (settled) break;
  }
  Chol2 l;
  if (!Cholesky(cov, &l)) return false;
  *out = EvaluateGrid(pts, like, centre, l, 161, 7.0);
  return true;
}

// Median, central 68.27 % interval and sd of weighted values (the weights sum to 1): the
// percentiles interpolate the weighted CDF taken at each value's mid-weight.
Estimate WeightedSummary(const std::vector<double>& values, const std::vector<double>& weights) {
  std::vector<size_t> order(values.size());
  for (size_t k = 0; k < order.size(); ++k) order[k] = k;
  std::sort(order.begin(), order.end(), [&](size_t i, size_t j) { return values[i] < values[j]; });
  Estimate e;
  double mean = 0.0;
  for (size_t k = 0; k < values.size(); ++k) mean += weights[k] * values[k];
  double var = 0.0;
  for (size_t k = 0; k < values.size(); ++k) var += weights[k] * std::pow(values[k] - mean, 2);
  e.sd = std::sqrt(var);
  const double qs[3] = {kLo68, 0.5, kHi68};
  double* outs[3] = {&e.lo68, &e.median, &e.hi68};
  int next = 0;
  double cum = 0.0, prev_cdf = 0.0, prev_value = values.empty() ? NAN : values[order[0]];
  for (size_t k = 0; k < order.size() && next < 3; ++k) {
    const double w = weights[order[k]];
    const double cdf = cum + 0.5 * w;
    const double value = values[order[k]];
    while (next < 3 && qs[next] <= cdf) {
      const double f = cdf > prev_cdf ? (qs[next] - prev_cdf) / (cdf - prev_cdf) : 1.0;
      *outs[next] = k == 0 ? value : prev_value + std::clamp(f, 0.0, 1.0) * (value - prev_value);
      ++next;
    }
    cum += w;
    prev_cdf = cdf;
    prev_value = value;
  }
  while (next < 3) *outs[next++] = prev_value;
  return e;
}

const std::vector<std::string>& CoefficientNames(RelationKind kind) {
  static const std::vector<std::string> power = {"a", "alpha", "value_at_pivot"};
  static const std::vector<std::string> linear = {"intercept", "slope", "value_at_pivot"};
  return kind == RelationKind::kPowerLaw ? power : linear;
}

// The reported coefficients from the pivot-space line y = c0 + c1 u.
void MapCoefficients(RelationKind kind, double pivot, double c0, double c1, double out[3]) {
  if (kind == RelationKind::kPowerLaw) {
    out[0] = std::exp(c0 - c1 * std::log(pivot));  // a
    out[1] = c1;                                   // alpha
    out[2] = std::exp(c0);                         // X(pivot)
  } else {
    out[0] = c0 - c1;        // intercept (X at I = 0)
    out[1] = c1 / pivot;     // slope per unit abscissa
    out[2] = c0;             // X(pivot)
  }
}

void AddFlag(RelationFit* fit, const std::string& code, const std::string& reason) {
  for (RelationFlag& f : fit->flags) {
    if (f.code == code) {
      f.reason += "; " + reason;
      return;
    }
  }
  fit->flags.push_back({code, reason});
}

}  // namespace

const std::vector<std::string>& TrendMetricNames() {
  static const std::vector<std::string> names = {
      "fwhm_um", "fwhm_x_um",     "fwhm_y_um",        "r2_px2",
      "ellipticity", "total_fwhm_um", "total_ellipticity"};
  return names;
}

Estimate SummarizeDraws(std::vector<double> draws) {
  draws.erase(std::remove_if(draws.begin(), draws.end(),
                             [](double v) { return !std::isfinite(v); }),
              draws.end());
  Estimate e;
  if (draws.empty()) return e;
  e.sd = SampleSd(draws);
  double q[3];
  SelectPercentiles(draws, {kLo68, 0.5, kHi68}, q);
  e.lo68 = q[0];
  e.median = q[1];
  e.hi68 = q[2];
  return e;
}

double ChiSquarePValue(double chi2, int dof) {
  if (dof < 1 || !std::isfinite(chi2) || chi2 < 0.0) return NAN;
  return RegularizedGammaQ(0.5 * dof, 0.5 * chi2);
}

const char* RelationKindName(RelationKind kind) {
  return kind == RelationKind::kPowerLaw ? "power_law" : "linear";
}

std::string RelationName(const std::string& metric, RelationKind kind) {
  return metric + (kind == RelationKind::kPowerLaw ? "_vs_wavelength" : "_vs_intensity");
}

RelationPoint RelationPoint::FromDraws(std::string label, double abscissa,
                                       std::vector<double> draws,
                                       std::vector<double> prior_draws) {
  RelationPoint p;
  p.label = std::move(label);
  p.abscissa = abscissa;
  p.draws = std::move(draws);
  p.prior_draws = std::move(prior_draws);
  return p;
}

RelationPoint RelationPoint::FromGaussian(std::string label, double abscissa, double median,
                                          double sd) {
  RelationPoint p;
  p.label = std::move(label);
  p.abscissa = abscissa;
  p.median = median;
  p.sd = sd;
  return p;
}

RelationPoint RelationPoint::Missing(std::string label, double abscissa, std::string reason) {
  RelationPoint p;
  p.label = std::move(label);
  p.abscissa = abscissa;
  p.missing_reason = reason.empty() ? "fit failed" : std::move(reason);
  return p;
}

bool RelationOptions::IsValid(std::string* error) const {
  if (resamples < 100) {
    *error = "relation resamples must be >= 100 (got " + std::to_string(resamples) + ")";
    return false;
  }
  if (!std::isnan(pivot) && !(pivot > 0.0 && std::isfinite(pivot))) {
    *error = "relation pivot must be a finite number > 0 (got " + Num(pivot) + ")";
    return false;
  }
  if (!(min_relative_span >= 0.0) || !std::isfinite(min_relative_span)) {
    *error = "min_relative_span must be finite and >= 0";
    return false;
  }
  if (!(max_relative_half_width > 0.0)) {
    *error = "max_relative_half_width must be > 0";
    return false;
  }
  if (!(scatter_p_value > 0.0 && scatter_p_value < 1.0)) {
    *error = "scatter_p_value must be in (0, 1)";
    return false;
  }
  return true;
}

const Coefficient* RelationFit::Find(const std::string& name) const {
  for (const Coefficient& c : coefficients) {
    if (c.name == name) return &c;
  }
  return nullptr;
}

bool RelationFit::HasFlag(const std::string& code) const {
  for (const RelationFlag& f : flags) {
    if (f.code == code) return true;
  }
  return false;
}

std::vector<double> RelationFit::ValueDraws(double x) const {
  std::vector<double> out;
  if (!fitted) return out;
  const Coefficient* at_pivot = Find("value_at_pivot");
  const Coefficient* shape = Find(kind == RelationKind::kPowerLaw ? "alpha" : "slope");
  if (at_pivot == nullptr || shape == nullptr) return out;
  const size_t n = std::min(at_pivot->draws.size(), shape->draws.size());
  out.resize(n);
  for (size_t r = 0; r < n; ++r) {
    out[r] = kind == RelationKind::kPowerLaw
                 ? at_pivot->draws[r] * std::pow(x / pivot, shape->draws[r])
                 : at_pivot->draws[r] + shape->draws[r] * (x - pivot);
  }
  return out;
}

double RelationFit::MinAbscissa() const {
  double m = NAN;
  for (const PointSummary& p : points) m = std::isnan(m) ? p.abscissa : std::min(m, p.abscissa);
  return m;
}

double RelationFit::MaxAbscissa() const {
  double m = NAN;
  for (const PointSummary& p : points) m = std::isnan(m) ? p.abscissa : std::max(m, p.abscissa);
  return m;
}

std::optional<RelationFit> FitRelation(RelationKind kind, const std::vector<RelationPoint>& points,
                                       const RelationOptions& options, std::string* error) {
  if (!options.IsValid(error)) return std::nullopt;
  const bool power = kind == RelationKind::kPowerLaw;
  const double pivot = std::isnan(options.pivot)
                           ? (power ? kReferenceWavelengthNm : kReferenceIntensityE)
                           : options.pivot;
  RelationFit fit;
  fit.kind = kind;
  fit.pivot = pivot;
  fit.resamples = options.resamples;
  fit.seed = options.seed;
  for (const std::string& name : CoefficientNames(kind)) {
    Coefficient c;
    c.name = name;
    fit.coefficients.push_back(c);
  }

  // Usable points, their likelihoods, and gaps.
  std::vector<UsablePoint> usable;
  std::vector<PointLikelihood> like;
  for (const RelationPoint& p : points) {
    UsablePoint up;
    std::string why = PreparePoint(kind, p, pivot, &up);
    if (why.empty()) {
      PointLikelihood l = up.gaussian ? PointLikelihood::Gaussian(up.y_mean, up.y_sd)
                                      : PointLikelihood::FromDraws(up.y_draws, up.prior_y);
      // A setting whose data do not bound the metric from below: its likelihood at the
      // smallest value its prior allows is within 2 sigma (e^-2) of its best. In pixel_centre
      // sampling that is a CCD width below ~0.25 px, which leaves no trace in the data. Its
      // likelihood for X is then the prior's geometry more than the data (for the FWHM, the
      // level sets of sqrt(sigma_x sigma_y) that reach the identified edge in both axes are
      // rare), and it pulled the Table-1 800 nm line down at low intensity, so it is not fitted.
      if (l.prior_divided()) {
        const double y_min = *std::min_element(up.prior_y.begin(), up.prior_y.end());
        if (l(y_min) > -2.0) {
          const Estimate& v = up.value;
          why = "bound only: the data do not bound it from below (its likelihood at the "
                "prior's smallest value, " + Num(kind == RelationKind::kPowerLaw ? std::exp(y_min) : y_min) +
                ", is within 2 sigma of its best); posterior median " + Num(v.median) +
                ", 84th percentile " + Num(v.hi68) + "; not fitted";
        }
      }
      if (why.empty()) {
        usable.push_back(std::move(up));
        like.push_back(l);
        continue;
      }
    }
    fit.gaps.push_back({p.label, p.abscissa, why});
  }
  const int n = static_cast<int>(usable.size());
  for (const UsablePoint& up : usable) {
    PointSummary ps;
    ps.label = up.label;
    ps.abscissa = up.x;
    ps.value = up.value;
    ps.fit_sd = up.s;
    ps.gaussian = up.gaussian;
    ps.num_draws = static_cast<int>(up.y_draws.size());
    fit.points.push_back(ps);
  }
  {
    std::string gaussian_labels;
    int num_gaussian = 0;
    for (const UsablePoint& up : usable) {
      if (!up.gaussian) continue;
      ++num_gaussian;
      gaussian_labels += (gaussian_labels.empty() ? "" : ", ") + up.label;
    }
    if (num_gaussian > 0) {
      AddFlag(&fit, kFlagGaussianApproximation,
              std::to_string(num_gaussian) + " point(s) without posterior draws (" +
                  gaussian_labels + "): a Gaussian from their median and sd was used");
    }
  }

  if (n < 2) {
    AddFlag(&fit, kFlagNotFitted,
            std::to_string(n) + " usable point(s): a relation needs at least 2");
    return fit;
  }
  double u_min = usable[0].u, u_max = usable[0].u;
  double x_min = usable[0].x, x_max = usable[0].x;
  for (const UsablePoint& up : usable) {
    u_min = std::min(u_min, up.u);
    u_max = std::max(u_max, up.u);
    x_min = std::min(x_min, up.x);
    x_max = std::max(x_max, up.x);
  }
  if (!(u_max - u_min > 1e-12)) {
    AddFlag(&fit, kFlagNotFitted,
            "all " + std::to_string(n) + " usable points are at abscissa " + Num(x_min) +
                ": the slope is undefined");
    return fit;
  }

  // Weighted least squares on the point medians, weights 1 / s_i^2: the grid's first centre
  // and scale. M = A^T W A; the solution M^-1 A^T W y, covariance M^-1.
  double m00 = 0.0, m01 = 0.0, m11 = 0.0, r0 = 0.0, r1 = 0.0;
  for (int i = 0; i < n; ++i) {
    const double w = 1.0 / (usable[i].s * usable[i].s);
    m00 += w;
    m01 += w * usable[i].u;
    m11 += w * usable[i].u * usable[i].u;
    r0 += w * usable[i].y_center;
    r1 += w * usable[i].u * usable[i].y_center;
  }
  const double det = m00 * m11 - m01 * m01;
  if (!(det > 0.0) || !std::isfinite(det)) {
    AddFlag(&fit, kFlagNotFitted, "the weighted normal equations are singular");
    return fit;
  }
  const double wls[2] = {(m11 * r0 - m01 * r1) / det, (m00 * r1 - m01 * r0) / det};
  const Sym2 wls_cov{m11 / det, -m01 / det, m00 / det};

  // The (c0, c1) posterior on a grid.
  for (int i = 0; i < n; ++i) fit.points[i].prior_divided = like[i].prior_divided();
  GridPosterior grid;
  if (!SolveGrid(usable, like, wls, wls_cov, &grid)) {
    AddFlag(&fit, kFlagNotFitted, "the posterior of the relation's coefficients is degenerate");
    return fit;
  }
  const size_t nodes = grid.w.size();
  const double c0_med = WeightedSummary(grid.c0, grid.w).median;
  const double c1_med = WeightedSummary(grid.c1, grid.w).median;

  // Goodness of fit of the point medians about the median relation.
  double chi2 = 0.0;
  for (int i = 0; i < n; ++i) {
    const double z = (usable[i].y_center - c0_med - c1_med * usable[i].u) / usable[i].s;
    fit.points[i].normalized_residual = z;
    chi2 += z * z;
  }
  fit.dof = n - 2;
  if (fit.dof >= 1) {
    fit.chi2 = chi2;
    fit.p_value = ChiSquarePValue(chi2, fit.dof);
    fit.scale_factor = std::sqrt(chi2 / fit.dof);
  }

  // Coefficient estimates from the nodes, primary and inflated.
  const double inflate = fit.dof >= 1 ? std::max(1.0, fit.scale_factor) : NAN;
  std::vector<std::vector<double>> values(3, std::vector<double>(nodes));
  std::vector<std::vector<double>> inflated(3, std::vector<double>(nodes));
  for (size_t k = 0; k < nodes; ++k) {
    double v[3];
    MapCoefficients(kind, pivot, grid.c0[k], grid.c1[k], v);
    for (int j = 0; j < 3; ++j) values[j][k] = v[j];
    if (fit.dof >= 1 && inflate > 1.0) {
      MapCoefficients(kind, pivot, c0_med + inflate * (grid.c0[k] - c0_med),
                      c1_med + inflate * (grid.c1[k] - c1_med), v);
      for (int j = 0; j < 3; ++j) inflated[j][k] = v[j];
    }
  }
  for (int j = 0; j < 3; ++j) {
    fit.coefficients[j].estimate = WeightedSummary(values[j], grid.w);
    if (fit.dof >= 1) {
      fit.coefficients[j].inflated = inflate > 1.0 ? WeightedSummary(inflated[j], grid.w)
                                                   : fit.coefficients[j].estimate;
    }
  }

  // Propagation draws: a node by weight, jittered uniformly within its cell.
  {
    std::vector<double> cdf(nodes);
    double cum = 0.0;
    for (size_t k = 0; k < nodes; ++k) cdf[k] = (cum += grid.w[k]);
    std::mt19937_64 engine(DeriveSeed(options.seed, 0));
    const int num_r = options.resamples;
    for (Coefficient& c : fit.coefficients) c.draws.resize(num_r);
    for (int r = 0; r < num_r; ++r) {
      const double target = Uniform01(engine) * cum;
      const size_t k = std::min<size_t>(
          static_cast<size_t>(std::lower_bound(cdf.begin(), cdf.end(), target) - cdf.begin()),
          nodes - 1);
      const double j0 = (Uniform01(engine) - 0.5) * grid.dz;
      const double j1 = (Uniform01(engine) - 0.5) * grid.dz;
      const double c0 = grid.c0[k] + grid.l.l00 * j0;
      const double c1 = grid.c1[k] + grid.l.l10 * j0 + grid.l.l11 * j1;
      double v[3];
      MapCoefficients(kind, pivot, c0, c1, v);
      for (int j = 0; j < 3; ++j) fit.coefficients[j].draws[r] = v[j];
    }
  }
  fit.fitted = true;

  // Flags.
  if (fit.dof == 0) {
    AddFlag(&fit, kFlagPoorlyConstrained,
            "2 points, 0 degrees of freedom: the relation passes through both points; the "
            "interval rests on the point errors alone and cannot be checked against the "
            "scatter");
  } else if (fit.dof == 1) {
    AddFlag(&fit, kFlagPoorlyConstrained,
            "3 points, 1 degree of freedom: the interval rests on the point errors alone and "
            "cannot be checked against the scatter");
  }
  const double relative_span = (x_max - x_min) / pivot;
  if (relative_span < options.min_relative_span) {
    AddFlag(&fit, kFlagPoorlyConstrained,
            "abscissa span " + Num(x_min) + " to " + Num(x_max) + " is " +
                Num(100.0 * relative_span) + " % of the pivot " + Num(pivot) + " (< " +
                Num(100.0 * options.min_relative_span) + " %): a short lever arm");
  }
  for (const Coefficient& c : fit.coefficients) {
    if (c.name != "alpha" && c.name != "slope" && c.name != "value_at_pivot") continue;
    const double half = 0.5 * (c.estimate.hi68 - c.estimate.lo68);
    const double rel = half / std::fabs(c.estimate.median);
    if (!(rel <= options.max_relative_half_width)) {
      AddFlag(&fit, kFlagPoorlyConstrained,
              c.name + ": 68 % half-width " + Num(half) + " is " +
                  (std::isfinite(rel) ? Num(100.0 * rel) + " %" : std::string("infinitely many %")) +
                  " of |median| " + Num(std::fabs(c.estimate.median)) + " (> " +
                  Num(100.0 * options.max_relative_half_width) + " %)");
    }
  }
  if (fit.dof >= 1 && fit.p_value < options.scatter_p_value && fit.scale_factor > 1.0) {
    AddFlag(&fit, kFlagScatterExceedsErrors,
            "chi2 = " + Num(fit.chi2) + " for " + std::to_string(fit.dof) + " dof (p = " +
                Num(fit.p_value) + " < " + Num(options.scatter_p_value) +
                "): the points scatter more than their uncertainties; intervals inflated by " +
                Num(inflate) + " are in 'inflated'");
  }
  return fit;
}

json ToJson(const Estimate& e) {
  return json{{"median", NullIfNan(e.median)},
              {"lo68", NullIfNan(e.lo68)},
              {"hi68", NullIfNan(e.hi68)},
              {"sd", NullIfNan(e.sd)}};
}

json ToJson(const RelationFit& fit) {
  const bool power = fit.kind == RelationKind::kPowerLaw;
  json j;
  j["kind"] = RelationKindName(fit.kind);
  j["model"] = power ? "X = a * wavelength_nm^alpha" : "X = intercept + slope * intensity_e";
  j["abscissa"] = power ? "wavelength_nm" : "intensity_e";
  j["abscissa_errors"] = "none: abscissae are treated as exact";
  j["pivot"] = fit.pivot;
  j["fitted"] = fit.fitted;
  for (const Coefficient& c : fit.coefficients) j[c.name] = ToJson(c.estimate);
  if (fit.fitted && fit.dof >= 1) {
    json inflated;
    inflated["scale_factor"] = std::max(1.0, fit.scale_factor);
    for (const Coefficient& c : fit.coefficients) inflated[c.name] = ToJson(c.inflated);
    j["inflated"] = inflated;
  } else {
    j["inflated"] = nullptr;
  }
  const bool have_chi2 = fit.fitted && fit.dof >= 1;
  j["chi2"] = have_chi2 ? NullIfNan(fit.chi2) : json(nullptr);
  j["dof"] = fit.dof;
  j["chi2_per_dof"] = have_chi2 ? NullIfNan(fit.chi2 / fit.dof) : json(nullptr);
  j["p_value"] = have_chi2 ? NullIfNan(fit.p_value) : json(nullptr);
  j["n_points"] = fit.points.size();
  json pts = json::array();
  for (const PointSummary& p : fit.points) {
    pts.push_back({{"label", p.label},
                   {"abscissa", p.abscissa},
                   {"value", ToJson(p.value)},
                   {"fit_sd", NullIfNan(p.fit_sd)},
                   {"source", p.gaussian ? "gaussian_median_sd" : "posterior_draws"},
                   {"n_draws", p.num_draws},
                   {"prior_divided", p.prior_divided},
                   {"normalized_residual", NullIfNan(p.normalized_residual)}});
  }
  j["points"] = pts;
  json gaps = json::array();
  for (const RelationGap& g : fit.gaps) {
    gaps.push_back({{"label", g.label}, {"abscissa", NullIfNan(g.abscissa)}, {"reason", g.reason}});
  }
  j["gaps"] = gaps;
  json flags = json::array();
  for (const RelationFlag& f : fit.flags) flags.push_back({{"flag", f.code}, {"reason", f.reason}});
  j["flags"] = flags;
  j["resamples"] = fit.resamples;
  j["seed"] = fit.seed;
  return j;
}

std::optional<CombinedValue> EvaluateCombined(const RelationFit* vs_intensity,
                                              const RelationFit& vs_wavelength,
                                              double intensity_e, double wavelength_nm,
                                              double reference_intensity_e, std::string* error) {
  if (!std::isfinite(intensity_e) || !std::isfinite(wavelength_nm) || wavelength_nm <= 0.0 ||
      !std::isfinite(reference_intensity_e)) {
    *error = "combined model: intensity, wavelength (> 0) and I0 must be finite";
    return std::nullopt;
  }
  if (vs_wavelength.kind != RelationKind::kPowerLaw) {
    *error = "combined model: the wavelength relation must be a power law";
    return std::nullopt;
  }
  if (!vs_wavelength.fitted) {
    *error = "combined model: the wavelength relation was not fitted";
    return std::nullopt;
  }
  CombinedValue out;
  out.draws = vs_wavelength.ValueDraws(wavelength_nm);
  if (wavelength_nm < vs_wavelength.MinAbscissa() ||
      wavelength_nm > vs_wavelength.MaxAbscissa()) {
    out.notes.push_back("wavelength " + Num(wavelength_nm) + " nm is outside the fitted range " +
                        Num(vs_wavelength.MinAbscissa()) + "-" +
                        Num(vs_wavelength.MaxAbscissa()) + " nm: extrapolated");
  }
  const bool at_reference =
      std::fabs(intensity_e - reference_intensity_e) <= 1e-9 * std::fabs(reference_intensity_e);
  if (!at_reference) {
    if (vs_intensity == nullptr) {
      *error = "combined model: no intensity relation (needed away from I0)";
      return std::nullopt;
    }
    if (vs_intensity->kind != RelationKind::kLinear) {
      *error = "combined model: the intensity relation must be linear";
      return std::nullopt;
    }
    if (!vs_intensity->fitted) {
      *error = "combined model: the intensity relation was not fitted";
      return std::nullopt;
    }
    const std::vector<double> at_i = vs_intensity->ValueDraws(intensity_e);
    const std::vector<double> at_i0 = vs_intensity->ValueDraws(reference_intensity_e);
    const size_t pairs = std::min(out.draws.size(), at_i.size());
    out.draws.resize(pairs);
    size_t bad = 0;
    for (size_t r = 0; r < pairs; ++r) {
      if (!(at_i0[r] > 0.0)) {
        ++bad;
        continue;
      }
      out.draws[r] *= at_i[r] / at_i0[r];
    }
    if (bad > 0) {
      *error = "combined model: the intensity relation is <= 0 at I0 = " +
               Num(reference_intensity_e) + " on " + std::to_string(bad) + " of " +
               std::to_string(pairs) + " draws";
      return std::nullopt;
    }
    if (intensity_e < vs_intensity->MinAbscissa() || intensity_e > vs_intensity->MaxAbscissa()) {
      out.notes.push_back("intensity " + Num(intensity_e) + " e- is outside the fitted range " +
                          Num(vs_intensity->MinAbscissa()) + "-" +
                          Num(vs_intensity->MaxAbscissa()) + " e-: extrapolated");
    }
  }
  out.estimate = SummarizeDraws(out.draws);
  return out;
}

}  // namespace ccdpsf::trend
