// Photon transfer with pixel covariances (ptc.h): flat pairs, their covariances and the
// weighted least-squares fit of Astier et al.'s model.
#include "ccdpsf/ptc.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

#include "ccdpsf/ptc_model.h"
#include "internal/json_number.h"

namespace ccdpsf {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

// A pair needs this many kept pixels to give covariances worth weighting (their relative
// sampling sd is then below 15 %).
constexpr long long kMinPairPixels = 100;
constexpr int kMinPairs = 3;
constexpr int kMaxLag = 8;
// Levenberg-Marquardt: at most this many steps per weighting; stop when chi2 falls by less
// than kChi2Tolerance (relative) on an accepted step.
constexpr int kMaxSteps = 200;
constexpr double kChi2Tolerance = 1e-12;
// Weightings (the weights from the latest model) at most; stop when no weight changes by more
// than kWeightTolerance (relative).
constexpr int kMaxWeightings = 8;
constexpr double kWeightTolerance = 1e-8;
// The read noise is given when its variance is positive by this many sd.
constexpr double kReadNoiseSignificance = 2.0;
// A pair whose frames' levels differ by more than this fraction was probably not taken under
// the same illumination.
constexpr double kMaxPairLevelChange = 0.05;
// chi2 / dof beyond this (a 5-sd excess for ~300 dof) is said in a warning.
constexpr double kChi2Warning = 1.4;

std::string Format(const char* format, double value) {
  char text[128];
  std::snprintf(text, sizeof(text), format, value);
  return text;
}

// One covariance to fit.
struct Point {
  int pair;   // index into the result's pairs
  int lag;    // lag index
  double mu;  // level [ADU]
  double y;   // covariance [ADU^2]
  double n;   // products N_ij
};

// Parameter layout: g, a (lags), [b (lags)], n (lags).
struct Layout {
  int lags = 0;
  bool with_b = false;
  int a() const { return 1; }
  int b() const { return 1 + lags; }
  int n() const { return 1 + (with_b ? 2 : 1) * lags; }
  int size() const { return 1 + (with_b ? 3 : 2) * lags; }
};

// The model at every point (ADU^2) and, when jacobian is not null, its derivatives.
void ModelAt(const PtcCovarianceModel& model, const Layout& layout,
             const std::vector<Point>& points, const Eigen::VectorXd& theta,
             Eigen::VectorXd* values, Eigen::MatrixXd* jacobian) {
  const double g = theta(0);
  const Eigen::VectorXd a = theta.segment(layout.a(), layout.lags);
  const Eigen::VectorXd b =
      layout.with_b ? Eigen::VectorXd(theta.segment(layout.b(), layout.lags)) : Eigen::VectorXd();
  const Eigen::VectorXd n = theta.segment(layout.n(), layout.lags);
  values->resize(points.size());
  if (jacobian != nullptr) jacobian->setZero(points.size(), layout.size());
  // Points come grouped by pair: evaluate K once per level.
  int last_pair = -1;
  Eigen::VectorXd k, dk_dmu;
  Eigen::MatrixXd dk_da, dk_db;
  for (size_t p = 0; p < points.size(); ++p) {
    const Point& pt = points[p];
    if (pt.pair != last_pair) {
      model.Evaluate(a, b, g * pt.mu, &k, jacobian ? &dk_da : nullptr,
                     jacobian && layout.with_b ? &dk_db : nullptr, jacobian ? &dk_dmu : nullptr);
      last_pair = pt.pair;
    }
    const int l = pt.lag;
    const double c = (k(l) + n(l)) / (g * g);
    (*values)(p) = c;
    if (jacobian == nullptr) continue;
    (*jacobian)(p, 0) = dk_dmu(l) * pt.mu / (g * g) - 2.0 * c / g;
    jacobian->block(p, layout.a(), 1, layout.lags) = dk_da.row(l) / (g * g);
    if (layout.with_b) jacobian->block(p, layout.b(), 1, layout.lags) = dk_db.row(l) / (g * g);
    (*jacobian)(p, layout.n() + l) = 1.0 / (g * g);
  }
}

// The sampling sd of each point from the model's variance at its level.
Eigen::VectorXd PointSd(const PtcCovarianceModel& model, const Layout& layout,
                        const std::vector<Point>& points, const Eigen::VectorXd& theta) {
  Eigen::VectorXd values;
  std::vector<Point> variances = points;
  for (Point& p : variances) p.lag = 0;
  ModelAt(model, layout, variances, theta, &values, nullptr);
  Eigen::VectorXd sd(points.size());
  for (size_t p = 0; p < points.size(); ++p) {
    const double c00 = std::max(values(p), 1e-12);
    sd(p) = c00 * std::sqrt((points[p].lag == 0 ? 2.0 : 1.0) / points[p].n);
  }
  return sd;
}

struct FitOutcome {
  bool ok = false;
  Eigen::VectorXd theta;
  Eigen::MatrixXd covariance;  // unscaled
  double chi2 = 0.0;
  int steps = 0;
  Eigen::VectorXd sd;  // the points' sds of the final weighting
};

// Levenberg-Marquardt on chi2 = sum ((y - C) / sd)^2 with fixed sds, from theta. Columns of
// the whitened Jacobian are scaled to unit length before solving (the parameters differ by
// ten orders of magnitude: g ~ 1, a ~ 1e-7, n ~ 10).
bool Minimise(const PtcCovarianceModel& model, const Layout& layout,
              const std::vector<Point>& points, const Eigen::VectorXd& sd, Eigen::VectorXd* theta,
              double* chi2_out, int* steps) {
  const int m = static_cast<int>(points.size());
  Eigen::VectorXd y(m);
  for (int p = 0; p < m; ++p) y(p) = points[p].y;
  Eigen::VectorXd values;
  Eigen::MatrixXd jacobian;
  ModelAt(model, layout, points, *theta, &values, &jacobian);
  double chi2 = ((y - values).cwiseQuotient(sd)).squaredNorm();
  double lambda = 1e-3;
  for (int step = 0; step < kMaxSteps; ++step) {
    ++*steps;
    const Eigen::MatrixXd whitened = sd.cwiseInverse().asDiagonal() * jacobian;
    const Eigen::VectorXd residual = (y - values).cwiseQuotient(sd);
    Eigen::VectorXd scale = whitened.colwise().norm().transpose();
    for (int j = 0; j < scale.size(); ++j) scale(j) = scale(j) > 0.0 ? 1.0 / scale(j) : 1.0;
    const Eigen::MatrixXd js = whitened * scale.asDiagonal();
    const Eigen::MatrixXd normal = js.transpose() * js;
    const Eigen::VectorXd gradient = js.transpose() * residual;
    bool accepted = false;
    while (lambda < 1e12) {
      Eigen::MatrixXd damped = normal;
      damped.diagonal().array() += lambda;
      const Eigen::VectorXd delta = scale.cwiseProduct(damped.ldlt().solve(gradient));
      const Eigen::VectorXd trial = *theta + delta;
      if (trial.allFinite() && trial(0) > 0.0) {
        Eigen::VectorXd trial_values;
        Eigen::MatrixXd trial_jacobian;
        ModelAt(model, layout, points, trial, &trial_values, &trial_jacobian);
        const double trial_chi2 = ((y - trial_values).cwiseQuotient(sd)).squaredNorm();
        if (std::isfinite(trial_chi2) && trial_chi2 <= chi2) {
          const double drop = chi2 - trial_chi2;
          *theta = trial;
          values = trial_values;
          jacobian = trial_jacobian;
          chi2 = trial_chi2;
          lambda = std::max(lambda / 10.0, 1e-12);
          accepted = true;
          if (drop <= kChi2Tolerance * std::max(chi2, 1.0)) {
            *chi2_out = chi2;
            return true;
          }
          break;
        }
      }
      lambda *= 10.0;
    }
    if (!accepted) break;  // no step lowers chi2: at the minimum to rounding
  }
  *chi2_out = chi2;
  return std::isfinite(chi2);
}

// Weighted least squares of y = X c, weights w; false when singular.
bool LinearFit(const Eigen::MatrixXd& x, const Eigen::VectorXd& y, const Eigen::VectorXd& w,
               Eigen::VectorXd* c) {
  const Eigen::MatrixXd normal = x.transpose() * w.asDiagonal() * x;
  Eigen::FullPivLU<Eigen::MatrixXd> lu(normal);
  if (!lu.isInvertible()) return false;
  *c = lu.solve(x.transpose() * w.asDiagonal() * y);
  return c->allFinite();
}

// The start: C_00 = c0 + mu / g + a_00 mu^2 and, per lag, C_ij = n_ij / g^2 + a_ij mu^2.
bool StartingPoint(const Layout& layout, const std::vector<Point>& points, Eigen::VectorXd* theta,
                   std::string* error) {
  *theta = Eigen::VectorXd::Zero(layout.size());
  double g = kNaN;
  for (int pass = 0; pass < 2; ++pass) {  // lag 0 first: it gives g
    for (int l = (pass == 0 ? 0 : 1); l < (pass == 0 ? 1 : layout.lags); ++l) {
      std::vector<const Point*> at;
      for (const Point& p : points) {
        if (p.lag == l) at.push_back(&p);
      }
      const int m = static_cast<int>(at.size());
      const int order = l == 0 ? 3 : 2;
      Eigen::MatrixXd x(m, order);
      Eigen::VectorXd y(m), w(m);
      for (int i = 0; i < m; ++i) {
        const double mu = at[i]->mu;
        x(i, 0) = 1.0;
        if (l == 0) {
          x(i, 1) = mu;
          x(i, 2) = mu * mu;
        } else {
          x(i, 1) = mu * mu;
        }
        y(i) = at[i]->y;
        // The variance's sampling variance, from the Poisson part alone.
        const double v = std::max(std::fabs(mu), 1.0);
        w(i) = at[i]->n / (v * v);
      }
      Eigen::VectorXd c;
      if (!LinearFit(x, y, w, &c)) {
        *error = "no ptc estimate: the levels do not determine the covariance at lag " +
                 std::to_string(l) + " (too few distinct levels?)";
        return false;
      }
      if (l == 0) {
        if (!(c(1) > 0.0)) {
          *error = "no ptc estimate: the variance does not grow with the level (slope " +
                   Format("%.3g", c(1)) + " ADU per ADU)";
          return false;
        }
        g = 1.0 / c(1);
        (*theta)(0) = g;
        (*theta)(layout.a()) = c(2);
        (*theta)(layout.n()) = c(0) * g * g;
      } else {
        (*theta)(layout.a() + l) = c(1);
        (*theta)(layout.n() + l) = c(0) * g * g;
      }
    }
  }
  return true;
}

// Fits with the weights of the latest model until they settle.
FitOutcome Fit(const PtcCovarianceModel& model, const Layout& layout,
               const std::vector<Point>& points, const Eigen::VectorXd& start) {
  FitOutcome out;
  out.theta = start;
  Eigen::VectorXd sd = PointSd(model, layout, points, out.theta);
  for (int round = 0; round < kMaxWeightings; ++round) {
    if (!Minimise(model, layout, points, sd, &out.theta, &out.chi2, &out.steps)) return out;
    const Eigen::VectorXd next = PointSd(model, layout, points, out.theta);
    const double change = ((next - sd).cwiseQuotient(sd)).cwiseAbs().maxCoeff();
    sd = next;
    if (change < kWeightTolerance) break;
  }
  // chi2 and the covariance with the final weights.
  Eigen::VectorXd values;
  Eigen::MatrixXd jacobian;
  ModelAt(model, layout, points, out.theta, &values, &jacobian);
  Eigen::VectorXd y(points.size());
  for (size_t p = 0; p < points.size(); ++p) y(p) = points[p].y;
  out.chi2 = ((y - values).cwiseQuotient(sd)).squaredNorm();
  const Eigen::MatrixXd whitened = sd.cwiseInverse().asDiagonal() * jacobian;
  Eigen::VectorXd scale = whitened.colwise().norm().transpose();
  for (int j = 0; j < scale.size(); ++j) scale(j) = scale(j) > 0.0 ? 1.0 / scale(j) : 1.0;
  const Eigen::MatrixXd js = whitened * scale.asDiagonal();
  Eigen::FullPivLU<Eigen::MatrixXd> lu(js.transpose() * js);
  if (!lu.isInvertible()) return out;
  out.covariance = scale.asDiagonal() * lu.inverse() * scale.asDiagonal();
  out.sd = sd;
  out.ok = out.theta.allFinite() && out.covariance.allFinite() && out.theta(0) > 0.0;
  return out;
}

std::string LagName(int i, int j) {
  return i < 10 && j < 10 ? std::to_string(i) + std::to_string(j)
                          : std::to_string(i) + "_" + std::to_string(j);
}

}  // namespace

const char* PtcModelName(PtcModelKind kind) { return kind == PtcModelKind::kAB ? "ab" : "a"; }

bool ParsePtcModel(const std::string& text, PtcModelKind* kind) {
  if (text == "a") {
    *kind = PtcModelKind::kA;
  } else if (text == "ab") {
    *kind = PtcModelKind::kAB;
  } else {
    return false;
  }
  return true;
}

bool PtcOptions::IsValid(std::string* error) const {
  if (max_lag < 1 || max_lag > kMaxLag) {
    *error = "the largest lag must be in [1, " + std::to_string(kMaxLag) + "] (got " +
             std::to_string(max_lag) + ")";
    return false;
  }
  return TransferFrameOptions::IsValid(error);
}

double PtcResult::ModelAdu2(int lag, double mu_adu) const {
  const double g = gain_e_per_adu.value;
  if (!(g > 0.0) || fitted_a.size() == 0 || lag < 0 || lag >= fitted_a.size()) return kNaN;
  PtcCovarianceModel model(max_lag);
  Eigen::VectorXd k;
  model.Evaluate(fitted_a, fitted_b, g * mu_adu, &k, nullptr, nullptr, nullptr);
  return (k(lag) + fitted_n(lag)) / (g * g);
}

bool EstimatePtc(const std::vector<FitsImage>& frames, const std::vector<std::string>& names,
                 const PtcOptions& options, PtcResult* result, std::string* error) {
  *result = PtcResult{};
  if (!options.IsValid(error)) return false;
  if (frames.empty()) {
    *error = "no flat frames given";
    return false;
  }
  const int L = options.max_lag;
  const int side = L + 1;
  result->max_lag = L;
  result->model = options.model;
  for (int j = 0; j <= L; ++j) {
    for (int i = 0; i <= L; ++i) result->lag_names.push_back(LagName(i, j));
  }
  std::vector<std::string>& warnings = result->warnings;
  TransferFrameSet set;
  if (!PrepareTransferFrames(frames, names, options, &set, &warnings, error)) return false;
  result->rounding_adu2 = set.rounding_adu2;
  const std::vector<std::pair<size_t, size_t>> pairs =
      FindIlluminationPairs(set, options, &warnings);
  if (pairs.empty()) {
    *error =
        "no flat pairs: ptc needs two frames of the same size under the same illumination "
        "(exposure time, scene, WAVELEN, FOCUSPOS) at each level; none among " +
        std::to_string(frames.size()) + " frames";
    return false;
  }
  DescribePairs(pairs, &set, &warnings);
  result->frames = set.info;
  const BiasEstimate bias = ResolveTransferBias(set, options, &warnings);
  if (!std::isfinite(bias.value)) {
    *error =
        "no bias level known (give --bias_adu, or BIASLVL, a bias section BIASSEC or "
        "zero-second frames): the covariance model needs levels measured from zero";
    return false;
  }
  result->bias_adu = bias.value;
  result->bias_sd_adu = bias.sd;
  result->bias_source = bias.source;

  // Covariances per pair, and the rules for using them.
  const double step = std::sqrt(12.0 * set.rounding_adu2);
  for (const auto& [i, j] : pairs) {
    PtcPair pair;
    pair.first = set.names[i];
    pair.second = set.names[j];
    pair.exptime_s = set.exptimes[i];
    pair.cov = MeasureFlatPair(set.frames[i], set.frames[j], bias.value, L);
    const FlatPairCovariance& c = pair.cov;
    const double ceiling = std::min(set.frames[i].ceiling, set.frames[j].ceiling);
    double full_scale = kInf;
    for (size_t f : {i, j}) {
      const FitsImage& image = *set.frames[f].image;
      if (std::isfinite(image.adc_min) && std::isfinite(image.adc_max)) {
        full_scale = std::min(full_scale, image.adc_min + kTransferFullScaleFraction *
                                                              (image.adc_max - image.adc_min));
      }
    }
    const double c00 = c.cov_adu2.empty() ? kNaN : c.cov_adu2[0];
    if (c.kept < kMinPairPixels || !std::isfinite(c00)) {
      pair.excluded_because = "fewer than 100 pixels kept";
    } else if (c.at_floor > kTransferMaxFloorFraction * c.region_pixels) {
      pair.excluded_because = "over 0.1 % of its pixels at the clipped black level";
    } else if (c.raw_mean_adu + kTransferTailSd * std::sqrt(std::max(c00, 0.0)) >
               ceiling - 0.5 * step) {
      pair.excluded_because = "its noise reaches the ADC's top or the saturation level";
    } else if (c.raw_mean_adu > full_scale) {
      pair.excluded_because = "within 10 % of the ADC's full scale";
    } else {
      pair.used = true;
    }
    const double level_change =
        std::fabs(c.mean_a_adu - c.mean_b_adu) / std::max(std::fabs(c.mean_adu), 1.0);
    if (pair.used && level_change > kMaxPairLevelChange) {
      warnings.push_back(pair.first + " and " + pair.second + ": levels differ by " +
                         Format("%.0f %%", 100.0 * level_change) +
                         " (really the same illumination?)");
    }
    result->pairs.push_back(std::move(pair));
  }
  // Points, grouped by pair (ModelAt evaluates each level once).
  std::vector<Point> points;
  double lo = kInf, hi = -kInf;
  for (size_t p = 0; p < result->pairs.size(); ++p) {
    const PtcPair& pair = result->pairs[p];
    if (!pair.used) continue;
    ++result->pairs_used;
    lo = std::min(lo, pair.cov.mean_adu);
    hi = std::max(hi, pair.cov.mean_adu);
    for (int l = 0; l < side * side; ++l) {
      if (pair.cov.products[l] > 0 && std::isfinite(pair.cov.cov_adu2[l])) {
        points.push_back({static_cast<int>(p), l, pair.cov.mean_adu, pair.cov.cov_adu2[l],
                          static_cast<double>(pair.cov.products[l])});
      }
    }
  }
  result->min_level_adu = result->pairs_used > 0 ? lo : kNaN;
  result->max_level_adu = result->pairs_used > 0 ? hi : kNaN;
  if (result->pairs_used < kMinPairs) {
    std::string why;
    for (const PtcPair& pair : result->pairs) {
      if (!pair.used) {
        why = "; e.g. " + pair.first + " - " + pair.second + ": " + pair.excluded_because;
        break;
      }
    }
    *error = "no ptc estimate: " + std::to_string(result->pairs_used) + " usable flat pair(s) of " +
             std::to_string(result->pairs.size()) + "; at least 3 levels are needed" + why;
    return false;
  }

  Layout layout;
  layout.lags = side * side;
  layout.with_b = options.model == PtcModelKind::kAB;
  Eigen::VectorXd start;
  if (!StartingPoint(layout, points, &start, error)) return false;
  const PtcCovarianceModel model(L);
  const FitOutcome fit = Fit(model, layout, points, start);
  if (!fit.ok) {
    *error = "no ptc estimate: the covariance model's fit did not converge to a positive gain";
    return false;
  }
  const int dof = static_cast<int>(points.size()) - layout.size();
  result->chi2 = fit.chi2;
  result->dof = dof;
  result->iterations = fit.steps;
  const double scale2 = dof > 0 ? std::max(1.0, fit.chi2 / dof) : 1.0;
  result->sd_scale = std::sqrt(scale2);
  const Eigen::MatrixXd cov = fit.covariance * scale2;
  auto value = [&](int index) {
    return PtcValue{fit.theta(index), std::sqrt(std::max(cov(index, index), 0.0))};
  };
  const double g = fit.theta(0);
  result->gain_e_per_adu = value(0);
  for (int l = 0; l < layout.lags; ++l) {
    result->a.push_back(value(layout.a() + l));
    result->n.push_back(value(layout.n() + l));
    if (layout.with_b) result->b.push_back(value(layout.b() + l));
  }
  result->fitted_a = fit.theta.segment(layout.a(), layout.lags);
  result->fitted_n = fit.theta.segment(layout.n(), layout.lags);
  if (layout.with_b) result->fitted_b = fit.theta.segment(layout.b(), layout.lags);
  result->a_covariance = cov.block(layout.a(), layout.a(), layout.lags, layout.lags);
  // The sum over all lags within the range: each lag (i, j) stands for its mirror images.
  {
    Eigen::VectorXd weights(layout.lags);
    for (int j = 0; j <= L; ++j) {
      for (int i = 0; i <= L; ++i) {
        weights(j * side + i) = (i > 0 ? 2.0 : 1.0) * (j > 0 ? 2.0 : 1.0);
      }
    }
    result->a_sum.value = weights.dot(result->fitted_a);
    result->a_sum.sd = std::sqrt(std::max(weights.dot(result->a_covariance * weights), 0.0));
  }
  // Read noise: RN^2 = n_00 - q g^2 [e-^2].
  {
    const double q = set.rounding_adu2;
    const int in = layout.n();
    const double rn2 = fit.theta(in) - q * g * g;
    const double dg = -2.0 * q * g;  // d RN^2 / d g
    const double var = cov(in, in) + dg * dg * cov(0, 0) + 2.0 * dg * cov(in, 0);
    const double sd = std::sqrt(std::max(var, 0.0));
    if (rn2 > kReadNoiseSignificance * sd && rn2 > 0.0) {
      result->read_noise_e = {std::sqrt(rn2), sd / (2.0 * std::sqrt(rn2))};
    } else {
      result->read_noise_upper_e = std::sqrt(std::max(0.0, rn2 + kReadNoiseSignificance * sd));
      warnings.push_back("read noise not significant: RN^2 = " + Format("%.3g", rn2) + " +- " +
                         Format("%.2g", sd) + " e-^2, RN < " +
                         Format("%.3g", result->read_noise_upper_e) + " e- (2 sd)");
    }
  }
  // Each used pair's model and weights; every pair's model at its level.
  for (size_t p = 0; p < result->pairs.size(); ++p) {
    PtcPair& pair = result->pairs[p];
    pair.model_adu2.assign(layout.lags, kNaN);
    pair.sd_adu2.assign(layout.lags, kNaN);
    if (!std::isfinite(pair.cov.mean_adu)) continue;
    for (int l = 0; l < layout.lags; ++l) {
      pair.model_adu2[l] = result->ModelAdu2(l, pair.cov.mean_adu);
    }
    const double c00 = std::max(pair.model_adu2[0], 1e-12);
    for (int l = 0; l < layout.lags; ++l) {
      if (pair.cov.products[l] > 0) {
        pair.sd_adu2[l] = c00 * std::sqrt((l == 0 ? 2.0 : 1.0) / pair.cov.products[l]);
      }
    }
  }
  if (dof > 0 && fit.chi2 / dof > kChi2Warning) {
    warnings.push_back(
        Format("the covariances scatter %.2g x more than their sampling errors "
               "(chi2/dof); the sds are scaled up accordingly",
               std::sqrt(fit.chi2 / dof)));
  }
  if (result->gain_e_per_adu.sd > 0.1 * g) {
    warnings.push_back(
        Format("the gain is uncertain to %.0f %%", 100.0 * result->gain_e_per_adu.sd / g));
  }
  return true;
}

bool EstimatePtcFromFiles(const std::vector<std::string>& paths, const PtcOptions& options,
                          PtcResult* result, std::string* error) {
  std::vector<FitsImage> frames;
  return ReadTransferFrames(paths, &frames, error) &&
         EstimatePtc(frames, paths, options, result, error);
}

namespace {

using internal::JsonNumber;

// {"median", "sd", "lo68", "hi68"}: the fit's estimate and its Gaussian 68 % interval.
nlohmann::json Interval(const PtcValue& v) {
  return {{"median", JsonNumber(v.value)},
          {"sd", JsonNumber(v.sd)},
          {"lo68", JsonNumber(v.value - v.sd)},
          {"hi68", JsonNumber(v.value + v.sd)}};
}

}  // namespace

nlohmann::json PtcJson(const PtcResult& r) {
  const int lags = static_cast<int>(r.lag_names.size());
  nlohmann::json a = nlohmann::json::object(), b = nlohmann::json::object(),
                 n = nlohmann::json::object();
  std::vector<std::string> a_names;
  for (int l = 0; l < lags && l < static_cast<int>(r.a.size()); ++l) {
    a["a_" + r.lag_names[l]] = Interval(r.a[l]);
    a_names.push_back("a_" + r.lag_names[l]);
    n["n_" + r.lag_names[l]] = Interval(r.n[l]);
    if (l < static_cast<int>(r.b.size())) b["b_" + r.lag_names[l]] = Interval(r.b[l]);
  }
  nlohmann::json matrix = nlohmann::json::array();
  for (int i = 0; i < r.a_covariance.rows(); ++i) {
    nlohmann::json row = nlohmann::json::array();
    for (int j = 0; j < r.a_covariance.cols(); ++j) row.push_back(JsonNumber(r.a_covariance(i, j)));
    matrix.push_back(row);
  }
  nlohmann::json read_noise = Interval(r.read_noise_e);
  read_noise["upper_2sd"] = JsonNumber(r.read_noise_upper_e);
  nlohmann::json pairs = nlohmann::json::array();
  for (const PtcPair& p : r.pairs) {
    nlohmann::json covariances = nlohmann::json::object();
    for (int l = 0; l < lags && l < static_cast<int>(p.cov.cov_adu2.size()); ++l) {
      covariances["C_" + r.lag_names[l]] = {
          {"adu2", JsonNumber(p.cov.cov_adu2[l])},
          {"sd_adu2",
           l < static_cast<int>(p.sd_adu2.size()) ? JsonNumber(p.sd_adu2[l]) : nlohmann::json()},
          {"model_adu2", l < static_cast<int>(p.model_adu2.size()) ? JsonNumber(p.model_adu2[l])
                                                                   : nlohmann::json()},
          {"products", p.cov.products[l]}};
    }
    nlohmann::json j = {{"files", {p.first, p.second}},
                        {"exptime_s", JsonNumber(p.exptime_s)},
                        {"mean_adu", JsonNumber(p.cov.mean_adu)},
                        {"mean_first_adu", JsonNumber(p.cov.mean_a_adu)},
                        {"mean_second_adu", JsonNumber(p.cov.mean_b_adu)},
                        {"pixels", p.cov.region_pixels},
                        {"pixels_kept", p.cov.kept},
                        {"masked",
                         {{"at_floor", p.cov.at_floor},
                          {"at_ceiling", p.cov.at_ceiling},
                          {"not_finite", p.cov.not_finite},
                          {"defects", p.cov.defects},
                          {"outliers", p.cov.outliers}}},
                        {"used", p.used},
                        {"covariances", covariances}};
    if (!p.used) j["excluded_because"] = p.excluded_because;
    pairs.push_back(j);
  }
  const nlohmann::json frames = TransferFramesJson(r.frames);
  nlohmann::json out = {
      {"gain_e_per_adu", Interval(r.gain_e_per_adu)},
      {"read_noise_e", read_noise},
      {"a", a},
      {"a_covariance", {{"names", a_names}, {"matrix", matrix}, {"unit", "1/e-^2"}}},
      {"a_sum_within_range",
       {{"value", JsonNumber(r.a_sum.value)},
        {"sd", JsonNumber(r.a_sum.sd)},
        {"definition", "a_00 + sum of the other a_ij over -L <= i, j <= L (mirror images)"}}},
      {"n", n},
      {"model",
       {{"name", PtcModelName(r.model)},
        {"max_lag", r.max_lag},
        {"equation",
         "C_ij(mu) = (K_ij(g mu) + n_ij) / g^2; K^(k) = mu f0(2 a^(k) mu) + (ab)^(k) mu^3 "
         "h(2 a^(k) mu), f0(x) = (e^x - 1) / x, h(x) = e^x / x - 2 (e^x - 1 - x) / x^3"},
        {"units",
         {{"mu", "ADU (bias subtracted)"},
          {"C_ij", "ADU^2"},
          {"a_ij", "1/e-"},
          {"b_ij", "1/e-"},
          {"n_ij", "e-^2"},
          {"gain", "e-/ADU"}}}}},
      {"fit",
       {{"chi2", r.chi2},
        {"dof", r.dof},
        {"sd_scale", r.sd_scale},
        {"steps", r.iterations},
        {"pairs_used", r.pairs_used},
        {"min_level_adu", JsonNumber(r.min_level_adu)},
        {"max_level_adu", JsonNumber(r.max_level_adu)}}},
      {"bias_adu", JsonNumber(r.bias_adu)},
      {"bias_sd_adu", JsonNumber(r.bias_sd_adu)},
      {"bias_source", r.bias_source},
      {"rounding_adu2", r.rounding_adu2},
      {"pairs", pairs},
      {"frames", frames},
      {"warnings", r.warnings}};
  if (!r.b.empty()) out["b"] = b;
  return out;
}

std::string PtcCsv(const PtcResult& r) {
  std::ostringstream csv;
  csv << "pair,mean_adu,lag_i,lag_j,cov_adu2,cov_sd_adu2,model_adu2,products,used\n";
  const int side = r.max_lag + 1;
  char line[256];
  for (size_t p = 0; p < r.pairs.size(); ++p) {
    const PtcPair& pair = r.pairs[p];
    for (int l = 0; l < static_cast<int>(pair.cov.cov_adu2.size()); ++l) {
      if (!std::isfinite(pair.cov.cov_adu2[l])) continue;
      const double sd = l < static_cast<int>(pair.sd_adu2.size()) ? pair.sd_adu2[l] : kNaN;
      const double model = l < static_cast<int>(pair.model_adu2.size()) ? pair.model_adu2[l] : kNaN;
      std::snprintf(line, sizeof(line), "%zu,%.10g,%d,%d,%.10g,%.6g,%.10g,%lld,%d\n", p + 1,
                    pair.cov.mean_adu, l % side, l / side, pair.cov.cov_adu2[l], sd, model,
                    pair.cov.products[l], pair.used ? 1 : 0);
      csv << line;
    }
  }
  return csv.str();
}

}  // namespace ccdpsf
