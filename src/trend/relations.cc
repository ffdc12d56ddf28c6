#include "ccdpsf/trend/relations.h"

#include <algorithm>
#include <cstdio>
#include <initializer_list>
#include <limits>
#include <map>
#include <random>

#include "ccdpsf/chi_square.h"
#include "ccdpsf/random.h"

namespace ccdpsf::trend {
namespace {

using nlohmann::json;

// Central 68.27 % interval: 1 sigma of a Gaussian (the same bounds as fit.json).
constexpr double kLo68 = 0.158655;
constexpr double kHi68 = 0.841345;
constexpr double kLo95 = 0.025;
constexpr double kHi95 = 0.975;

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

// A point ready for fitting, in the fitted space y (log X for the power law).
struct UsablePoint {
  std::string label;
  double x = NAN;
  double u = NAN;                 // transformed abscissa
  std::vector<double> y_draws;    // empty for a Gaussian point
  double y_mean = NAN, y_sd = NAN;  // Gaussian point's parameters in y
  double y_center = NAN;          // median in y
  double s = NAN;                 // sd in y: the weight is 1 / s^2
  Estimate value;                 // of X
  bool gaussian = false;
  int joint_set = -1;  // RelationPoint::joint_set
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
    if (p.joint_set >= 0 && finite.size() != p.draws.size()) {
      // Its draws would no longer be aligned with the other points' states.
      return "a joint fit's point with non-finite draws";
    }
    out->joint_set = p.joint_set;
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
  out->value.lo95 = p.median - 1.959964 * p.sd;
  out->value.hi95 = p.median + 1.959964 * p.sd;
  out->value.sd = p.sd;
  return "";
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

bool IsCcdOnlyMetric(const std::string& metric) { return metric.rfind("total_", 0) != 0; }

Estimate SummarizeDraws(std::vector<double> draws) {
  draws.erase(std::remove_if(draws.begin(), draws.end(),
                             [](double v) { return !std::isfinite(v); }),
              draws.end());
  Estimate e;
  if (draws.empty()) return e;
  e.sd = SampleSd(draws);
  double q[5];
  SelectPercentiles(draws, {kLo95, kLo68, 0.5, kHi68, kHi95}, q);
  e.lo95 = q[0];
  e.lo68 = q[1];
  e.median = q[2];
  e.hi68 = q[3];
  e.hi95 = q[4];
  return e;
}

const char* RelationKindName(RelationKind kind) {
  return kind == RelationKind::kPowerLaw ? "power_law" : "linear";
}

std::string RelationName(const std::string& metric, RelationKind kind) {
  return metric + (kind == RelationKind::kPowerLaw ? "_vs_wavelength" : "_vs_intensity");
}

RelationPoint RelationPoint::FromDraws(std::string label, double abscissa,
                                       std::vector<double> draws) {
  RelationPoint p;
  p.label = std::move(label);
  p.abscissa = abscissa;
  p.draws = std::move(draws);
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

RelationPoint RelationPoint::BoundOnly(std::string label, double abscissa, std::string reason,
                                       std::vector<double> draws) {
  RelationPoint p = Missing(std::move(label), abscissa, std::move(reason));
  p.draws = std::move(draws);
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

  // Usable points and gaps.
  std::vector<UsablePoint> usable;
  for (const RelationPoint& p : points) {
    UsablePoint up;
    const std::string why = PreparePoint(kind, p, pivot, &up);
    if (!why.empty()) {
      RelationGap gap{p.label, p.abscissa, why};
      if (!p.missing_reason.empty()) {
        std::vector<double> finite;
        for (double d : p.draws) {
          if (std::isfinite(d)) finite.push_back(d);
        }
        if (finite.size() >= 2) SelectPercentiles(finite, {0.95}, &gap.upper_limit_95);
      }
      fit.gaps.push_back(std::move(gap));
      continue;
    }
    usable.push_back(std::move(up));
  }
  // A joint set's points resample state by state: their draws must be as many.
  {
    std::map<int, size_t> set_draws;
    std::vector<UsablePoint> kept;
    for (UsablePoint& up : usable) {
      if (up.joint_set >= 0) {
        const size_t count = set_draws.emplace(up.joint_set, up.y_draws.size()).first->second;
        if (up.y_draws.size() != count) {
          fit.gaps.push_back({up.label, up.x,
                              "a joint fit's point with " + std::to_string(up.y_draws.size()) +
                                  " draws, its set's first has " + std::to_string(count)});
          continue;
        }
      }
      kept.push_back(std::move(up));
    }
    usable = std::move(kept);
  }
  // One joint fit's points only: its medians lie on its own relation (relations.h).
  const bool one_joint_fit =
      !usable.empty() && std::all_of(usable.begin(), usable.end(), [&](const UsablePoint& up) {
        return up.joint_set >= 0 && up.joint_set == usable[0].joint_set;
      });
  if (std::any_of(usable.begin(), usable.end(),
                  [](const UsablePoint& up) { return up.joint_set >= 0; })) {
    AddFlag(&fit, kFlagJointPoints,
            "points from one joint fit (an intensity series with the brighter-fatter slope): "
            "resampled state by state, so the intervals are the joint posterior's; the points "
            "lie on the fit's own curve, so chi^2 measures its bend, not the scatter");
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
    if (up.gaussian) {
      ps.fit_centre = up.value.median;
    } else {
      double sum = 0.0;
      for (double y : up.y_draws) sum += y;
      const double mean = sum / up.y_draws.size();
      ps.fit_centre = kind == RelationKind::kPowerLaw ? std::exp(mean) : mean;
    }
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

  // Weighted least squares: M = A^T W A, H = M^-1 A^T W, row 0 -> c0, row 1 -> c1.
  double m00 = 0.0, m01 = 0.0, m11 = 0.0;
  std::vector<double> w(n);
  for (int i = 0; i < n; ++i) {
    w[i] = 1.0 / (usable[i].s * usable[i].s);
    m00 += w[i];
    m01 += w[i] * usable[i].u;
    m11 += w[i] * usable[i].u * usable[i].u;
  }
  const double det = m00 * m11 - m01 * m01;
  if (!(det > 0.0) || !std::isfinite(det)) {
    AddFlag(&fit, kFlagNotFitted, "the weighted normal equations are singular");
    return fit;
  }
  std::vector<double> h0(n), h1(n);
  for (int i = 0; i < n; ++i) {
    h0[i] = (m11 - m01 * usable[i].u) * w[i] / det;
    h1[i] = (m00 * usable[i].u - m01) * w[i] / det;
  }

  // Resampling: point k draws from its own engine, so gaps do not shift the other streams;
  // a joint set's points take the states its own stream picks (relations.h, Randomness).
  const int num_r = options.resamples;
  std::map<int, std::vector<double>> joint_states;  // joint set -> a uniform per resampling
  for (const UsablePoint& up : usable) {
    if (up.joint_set < 0 || joint_states.count(up.joint_set) > 0) continue;
    std::mt19937_64 engine(
        DeriveSeed(DeriveSeed(options.seed, ~uint64_t{0}), static_cast<uint64_t>(up.joint_set)));
    std::vector<double>& states = joint_states[up.joint_set];
    for (int r = 0; r < num_r; ++r) states.push_back(Uniform01(engine));
  }
  std::vector<double> c0(num_r, 0.0), c1(num_r, 0.0);
  for (int i = 0; i < n; ++i) {
    const UsablePoint& up = usable[i];
    std::mt19937_64 engine(DeriveSeed(options.seed, static_cast<uint64_t>(i)));
    const size_t num_draws = up.y_draws.size();
    const std::vector<double>* states =
        up.joint_set >= 0 ? &joint_states.at(up.joint_set) : nullptr;
    for (int r = 0; r < num_r; ++r) {
      double y;
      if (up.gaussian) {
        y = up.y_mean + up.y_sd * StandardNormal(engine);
      } else {
        const double v = states != nullptr ? (*states)[r] : Uniform01(engine);
        size_t k = static_cast<size_t>(v * static_cast<double>(num_draws));
        if (k >= num_draws) k = num_draws - 1;
        y = up.y_draws[k];
      }
      c0[r] += h0[i] * y;
      c1[r] += h1[i] * y;
    }
  }

  // Goodness of fit of the point medians about the median relation.
  const double c0_med = Median(c0);
  const double c1_med = Median(c1);
  double chi2 = 0.0;
  for (int i = 0; i < n; ++i) {
    const double z = (usable[i].y_center - c0_med - c1_med * usable[i].u) / usable[i].s;
    fit.points[i].normalized_residual = z;
    chi2 += z * z;
  }
  fit.dof = n - 2;
  if (fit.dof >= 1) {
    fit.chi2 = chi2;
    fit.p_value = ChiSquareUpperTail(chi2, fit.dof);
    fit.scale_factor = std::sqrt(chi2 / fit.dof);
  }

  // Coefficient draws, primary and inflated.
  const double inflate =
      fit.dof >= 1 ? (one_joint_fit ? 1.0 : std::max(1.0, fit.scale_factor)) : NAN;
  std::vector<std::vector<double>> inflated(3);
  for (Coefficient& c : fit.coefficients) c.draws.resize(num_r);
  for (int r = 0; r < num_r; ++r) {
    double v[3];
    MapCoefficients(kind, pivot, c0[r], c1[r], v);
    for (int j = 0; j < 3; ++j) fit.coefficients[j].draws[r] = v[j];
    if (fit.dof >= 1 && inflate > 1.0) {
      MapCoefficients(kind, pivot, c0_med + inflate * (c0[r] - c0_med),
                      c1_med + inflate * (c1[r] - c1_med), v);
      for (int j = 0; j < 3; ++j) inflated[j].push_back(v[j]);
    }
  }
  for (int j = 0; j < 3; ++j) {
    fit.coefficients[j].estimate = SummarizeDraws(fit.coefficients[j].draws);
    if (fit.dof >= 1) {
      fit.coefficients[j].inflated = inflate > 1.0 ? SummarizeDraws(std::move(inflated[j]))
                                                   : fit.coefficients[j].estimate;
    }
  }
  fit.fitted = true;

  // Flags.
  if (one_joint_fit) {
    // The dof and the scatter say nothing about one fit's own relation (kFlagJointPoints).
  } else if (fit.dof == 0) {
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
  if (!one_joint_fit && fit.dof >= 1 && fit.p_value < options.scatter_p_value &&
      fit.scale_factor > 1.0) {
    AddFlag(&fit, kFlagScatterExceedsErrors,
            "chi2 = " + Num(fit.chi2) + " for " + std::to_string(fit.dof) + " dof (p = " +
                Num(fit.p_value) + " < " + Num(options.scatter_p_value) +
                "): the points scatter more than their uncertainties; intervals inflated by " +
                Num(inflate) + " are in 'inflated'");
  }
  return fit;
}

json ToJson(const Estimate& e) {
  return json{{"median", NullIfNan(e.median)}, {"lo68", NullIfNan(e.lo68)},
              {"hi68", NullIfNan(e.hi68)},     {"lo95", NullIfNan(e.lo95)},
              {"hi95", NullIfNan(e.hi95)},     {"sd", NullIfNan(e.sd)}};
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
                   {"normalized_residual", NullIfNan(p.normalized_residual)}});
  }
  j["points"] = pts;
  json gaps = json::array();
  for (const RelationGap& g : fit.gaps) {
    gaps.push_back({{"label", g.label},
                    {"abscissa", NullIfNan(g.abscissa)},
                    {"reason", g.reason},
                    {"upper_limit_95", NullIfNan(g.upper_limit_95)}});
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
