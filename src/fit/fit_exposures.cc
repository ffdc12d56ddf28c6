// From calibrated exposures to a fit with a verdict (fit_exposures.h).
#include "ccdpsf/fit/fit_exposures.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "ccdpsf/fit/map_fit.h"

namespace ccdpsf::fit {
namespace {

std::string Fmt(double v, int digits = 3) {
  char text[48];
  std::snprintf(text, sizeof(text), "%.*g", digits, v);
  return text;
}

// Summed signal of a stamp's measured pixels [e-].
double Signal(const Stamp& s) {
  double total = 0.0;
  for (size_t q = 0; q < s.valid.size(); ++q) {
    if (s.valid[q]) total += s.electrons.data[q];
  }
  return total;
}

// Thresholds of ChooseFluxMode.
constexpr double kSameSignal = 0.03;
constexpr double kSameExptime = 0.01;
constexpr double kProportional = 0.05;

// Normalised residuals of every pixel of exposure k at theta (NaN where not measured).
std::vector<double> Residuals(const FitModel& model, FitEvaluator* ev, const double* theta, int k) {
  std::vector<double> m;
  ev->ModelImage(theta, k, &m, nullptr);
  const Stamp& s = model.stamps()[k];
  const PixelNoise noise = StampNoise(s);
  std::vector<double> z(m.size(), NAN);
  PixelValue v;
  for (size_t q = 0; q < m.size(); ++q) {
    if (!s.valid[q] || s.CensorAt(q) != Censor::kNone) continue;
    EvaluatePixel(LikelihoodKind::kGaussian, s.electrons.data[q], Censor::kNone, m[q], noise,
                  false, &v);
    z[q] = v.normalised;
  }
  return z;
}

}  // namespace

FluxMode ChooseFluxMode(const std::vector<Stamp>& stamps, std::string* why) {
  if (stamps.size() < 2) {
    *why = "one exposure";
    return FluxMode::kShared;
  }
  std::vector<double> signal, time;
  bool times_known = true;
  int censored = 0;
  for (const Stamp& s : stamps) {
    times_known = times_known && std::isfinite(s.info.exptime_s) && s.info.exptime_s > 0;
    // A censored pixel holds a lower or upper bound, not the signal: such an exposure's sum
    // says nothing about its flux.
    if (s.NumCensored() > 0) {
      ++censored;
      continue;
    }
    signal.push_back(Signal(s));
    time.push_back(s.info.exptime_s);
  }
  auto spread = [](const std::vector<double>& v) {
    const auto [lo, hi] = std::minmax_element(v.begin(), v.end());
    return *lo > 0 ? *hi / *lo - 1.0 : INFINITY;
  };
  if (signal.size() < 2) {
    // Too few exposures without censored pixels to compare their signals.
    std::vector<double> all_times;
    for (const Stamp& s : stamps) all_times.push_back(s.info.exptime_s);
    const std::string which = std::to_string(censored) + " of " + std::to_string(stamps.size()) +
                              " exposures have censored (saturated or clipped) pixels, so their "
                              "signals cannot be compared";
    if (times_known && spread(all_times) > kSameExptime) {
      *why = which + "; exposure times differ: a flux per exposure";
      return FluxMode::kPerExposure;
    }
    *why = which + "; " + (times_known ? "one exposure time" : "no exposure times") +
           ": one shared flux";
    return FluxMode::kShared;
  }
  const double signal_spread = spread(signal);
  if (times_known && spread(time) > kSameExptime) {
    std::vector<double> rate;
    for (size_t k = 0; k < signal.size(); ++k) rate.push_back(signal[k] / time[k]);
    const auto [tlo, thi] = std::minmax_element(time.begin(), time.end());
    const std::string times = "exposure times " + Fmt(*tlo) + "-" + Fmt(*thi) + " s";
    if (spread(rate) <= kProportional) {
      *why = times + ", signals proportional to them within " + Fmt(100 * spread(rate), 2) +
             " %: flux scaled by exposure time";
      return FluxMode::kExptimeScaled;
    }
    *why = times + ", signal per second differing by " + Fmt(100 * spread(rate), 2) +
           " % (shutter, lamp or saturation): a flux per exposure";
    return FluxMode::kPerExposure;
  }
  if (signal_spread <= kSameSignal) {
    *why = std::string(times_known ? "one exposure time" : "no exposure times") +
           ", signals within " + Fmt(100 * signal_spread, 2) + " %: one shared flux";
    return FluxMode::kShared;
  }
  *why = std::string(times_known ? "one exposure time" : "no exposure times") +
         " but signals differing by " + Fmt(100 * signal_spread, 2) + " %: a flux per exposure";
  return FluxMode::kPerExposure;
}

std::vector<OutlierMask> FindOutliers(const FitModel& model, const std::vector<double>& theta,
                                      const OutlierOptions& options) {
  std::vector<OutlierMask> out;
  if (!options.enabled) return out;
  const int n = model.num_exposures();
  std::unique_ptr<FitEvaluator> ev = model.NewEvaluator();
  std::vector<std::vector<double>> z(n);
  for (int k = 0; k < n; ++k) z[k] = Residuals(model, ev.get(), theta.data(), k);
  for (int k = 0; k < n; ++k) {
    const Stamp& s = model.stamps()[k];
    const double cx = theta[FitModel::XIndex(k)] - s.origin_x;
    const double cy = theta[FitModel::YIndex(k)] - s.origin_y;
    struct Candidate {
      size_t q;
      double z;
    };
    std::vector<Candidate> candidates;
    for (size_t q = 0; q < z[k].size(); ++q) {
      if (!(std::fabs(z[k][q]) >= options.threshold_sd)) continue;
      const int x = static_cast<int>(q % s.nx()), y = static_cast<int>(q / s.nx());
      bool mask = false;
      if (n >= 3) {
        // A transient: the same pixel fits in the other exposures.
        std::vector<double> others;
        for (int j = 0; j < n; ++j) {
          if (j != k && q < z[j].size() && std::isfinite(z[j][q])) others.push_back(std::fabs(z[j][q]));
        }
        if (!others.empty()) {
          std::nth_element(others.begin(), others.begin() + others.size() / 2, others.end());
          mask = others[others.size() / 2] < options.transient_others_sd;
        }
      } else {
        // A spike: far above the pixels at the same distance from the centre.
        const double r = std::hypot(x - cx, y - cy);
        double ring = 0.0;
        for (size_t p = 0; p < z[k].size(); ++p) {
          if (p == q || !std::isfinite(z[k][p])) continue;
          const int px = static_cast<int>(p % s.nx()), py = static_cast<int>(p / s.nx());
          if (std::max(std::abs(px - x), std::abs(py - y)) <= 1) continue;
          if (std::fabs(std::hypot(px - cx, py - cy) - r) >= 0.5) continue;
          ring = std::max(ring, std::fabs(z[k][p]));
        }
        mask = std::fabs(z[k][q]) >= options.spike_ratio * ring;
      }
      if (mask) candidates.push_back({q, z[k][q]});
    }
    std::sort(candidates.begin(), candidates.end(),
              [](const Candidate& a, const Candidate& b) { return std::fabs(a.z) > std::fabs(b.z); });
    if (static_cast<int>(candidates.size()) > options.max_per_exposure) {
      candidates.resize(options.max_per_exposure);
    }
    for (const Candidate& c : candidates) {
      const int x = static_cast<int>(c.q % s.nx()), y = static_cast<int>(c.q / s.nx());
      OutlierMask m;
      m.exposure = k;
      m.x_px = s.origin_x + x;
      m.y_px = s.origin_y + y;
      m.z = c.z;
      m.core = std::hypot(x - cx, y - cy) <= options.core_radius_px;
      out.push_back(m);
    }
  }
  return out;
}

bool FitExposures(const std::vector<Exposure>& exposures, const Quality& set_quality,
                  const ExposuresFitOptions& options, ExposuresFit* out, std::string* error) {
  *out = ExposuresFit();
  std::vector<Stamp> stamps;
  for (const Exposure& e : exposures) {
    stamps.push_back(e.stamp);
    out->calibration.push_back(e.report);
  }
  FitModelOptions model_options = options.config.model;
  if (stamps.size() > 1 && !options.flux_given) {
    std::string why;
    model_options.flux = ChooseFluxMode(stamps, &why);
    out->notes.push_back("flux: " + ToString(model_options.flux) + " (" + why +
                         "; --flux to choose)");
  } else if (stamps.size() > 1) {
    out->notes.push_back("flux: " + ToString(model_options.flux) + " (given)");
  }
  std::unique_ptr<FitModel> model = FitModel::Create(stamps, model_options, error);
  if (!model) return false;
  MapResult map;
  if (!FindMap(*model, options.config.fit.map, &map, error)) return false;

  // Outliers: mask, refit from where the MAP was, repeat.
  for (int round = 0; round < options.outliers.max_rounds; ++round) {
    const std::vector<OutlierMask> found = FindOutliers(*model, map.theta, options.outliers);
    if (found.empty()) break;
    for (const OutlierMask& m : found) {
      Stamp& s = stamps[m.exposure];
      s.valid[static_cast<size_t>(m.y_px - s.origin_y) * s.nx() + (m.x_px - s.origin_x)] = 0;
      out->outliers.push_back(m);
    }
    std::unique_ptr<FitModel> masked = FitModel::Create(stamps, model_options, error);
    if (!masked) return false;
    MapResult refit;
    std::string why;
    if (!RefineMap(*masked, map.theta, options.config.fit.map, &refit, &why) &&
        !FindMap(*masked, options.config.fit.map, &refit, error)) {
      return false;
    }
    model = std::move(masked);
    map = refit;
  }
  for (const OutlierMask& m : out->outliers) {
    const std::string text = "pixel (" + std::to_string(m.x_px) + ", " + std::to_string(m.y_px) +
                             ") stood z = " + Fmt(m.z, 3) + " from the model" +
                             (model->num_exposures() >= 3 ? " in this exposure alone"
                                                          : ", a lone spike") +
                             ": masked as a cosmic ray or hot pixel";
    if (m.core) {
      out->quality.Add("core_outlier_masked", Severity::kSuspect,
                       text + " (in the spot's core, which carries the width)", m.exposure);
    } else {
      out->quality.Add("outlier_masked", Severity::kNote, text, m.exposure);
    }
  }

  if (!RunFit(*model, options.config.fit, &out->result, error, &map)) return false;

  // The verdict: calibration's and the set's findings, then the fit's.
  for (size_t k = 0; k < exposures.size(); ++k) {
    for (const Finding& f : exposures[k].report.quality.findings) {
      out->quality.Add(f.code, f.severity,
                       exposures.size() > 1 ? "exposure " + std::to_string(k) + ": " + f.message
                                            : f.message,
                       static_cast<int>(k));
    }
  }
  for (const Finding& f : set_quality.findings) {
    out->quality.Add(f.code, f.severity,
                     f.exposure >= 0 && exposures.size() > 1
                         ? "exposure " + std::to_string(f.exposure) + ": " + f.message
                         : f.message,
                     f.exposure);
  }
  AssessFit(*model, out->result, options.quality, &out->quality);
  out->model = std::move(model);
  return true;
}

}  // namespace ccdpsf::fit
