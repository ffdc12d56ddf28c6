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
    EvaluatePixelWithPedestal(LikelihoodKind::kGaussian, s.electrons.data[q], Censor::kNone, m[q],
                              model.PedestalAt(theta), noise, false, &v);
    z[q] = v.normalised;
  }
  return z;
}

// Whether the spots' cores alone prove that the exposures hold different light, for when the
// wings are too faint to compare. The 5 x 5 box around a stamp's centre (its peak pixel) holds
// nearly all of a compact spot's light wherever in the pixel its centre falls, and a clipped,
// compressed or saturated core only lowers a box. So a box far below another's (by more than
// kCoreBoxSpread and 5 sd) means less light, unless that stamp's own core is cut: its peak
// must sit well below the brightest stamp's peak (not at a level where all are clipped) and
// none of its box pixels be saturated (censored from above; one censored from below, at a
// clipped black level, can only hold less).
constexpr double kCoreBoxSpread = 0.25;
bool CoresShowDifferentLight(const std::vector<Stamp>& stamps, std::string* what) {
  const Stamp& first = stamps[0];
  const int c = (first.nx() - 1) / 2;
  std::vector<double> box, variance, peak;
  std::vector<bool> censored;
  for (const Stamp& s : stamps) {
    double sum = 0.0, var = 0.0, top = -INFINITY;
    bool cut = false;
    for (int y = c - 2; y <= c + 2; ++y) {
      for (int x = c - 2; x <= c + 2; ++x) {
        if (x < 0 || y < 0 || x >= s.nx() || y >= s.ny()) continue;
        const size_t q = static_cast<size_t>(y) * s.nx() + x;
        // A pixel masked in any stamp is left out of every box.
        bool everywhere = true;
        for (const Stamp& o : stamps) everywhere = everywhere && o.valid[q];
        if (!everywhere) continue;
        const double v = s.electrons.data[q];
        sum += v;
        var += std::max(0.0, v) + s.read_noise_e * s.read_noise_e;
        top = std::max(top, v);
        cut = cut || s.CensorAt(q) == Censor::kAtOrAbove;
      }
    }
    box.push_back(sum);
    variance.push_back(var);
    peak.push_back(top);
    censored.push_back(cut);
  }
  const size_t lo = std::min_element(box.begin(), box.end()) - box.begin();
  const size_t hi = std::max_element(box.begin(), box.end()) - box.begin();
  const double top_peak = *std::max_element(peak.begin(), peak.end());
  if (!(box[lo] > 0) || censored[lo] || !(peak[lo] < 0.9 * top_peak)) return false;
  const bool differ = box[hi] > (1.0 + kCoreBoxSpread) * box[lo] &&
                      box[hi] - box[lo] > 5.0 * std::sqrt(variance[lo] + variance[hi]);
  if (differ) {
    *what = "but the spots' 5 x 5 cores hold " + Fmt(box[lo], 3) + " to " + Fmt(box[hi], 3) +
            " e- (exposures " + std::to_string(lo) + " and " + std::to_string(hi) +
            "; clipping or compression only lowers a core)";
  }
  return differ;
}

}  // namespace

FluxMode ChooseFluxMode(const std::vector<Stamp>& stamps, std::string* why) {
  if (stamps.size() < 2) {
    *why = "one exposure";
    return FluxMode::kShared;
  }
  // The light is compared outside the 3 x 3 core (a clipped, saturated, compressed or
  // cosmic-ray-hit core says nothing of the flux) over the pixels measured in every stamp:
  // stamps are centred on their peak pixel, so the same pixels hold the same part of the PSF
  // up to sub-pixel shifts, which move light between core and wings only in second order.
  const Stamp& first = stamps[0];
  const int c = (first.nx() - 1) / 2;
  std::vector<uint8_t> common(first.valid.size(), 1);
  for (const Stamp& s : stamps) {
    if (s.nx() != first.nx() || s.ny() != first.ny()) {
      *why = "stamps of different sizes";
      return FluxMode::kShared;
    }
    for (size_t q = 0; q < common.size(); ++q) {
      const int x = static_cast<int>(q % s.nx()), y = static_cast<int>(q / s.nx());
      if (!s.valid[q] || s.CensorAt(q) != Censor::kNone ||
          (std::abs(x - c) <= 1 && std::abs(y - c) <= 1)) {
        common[q] = 0;
      }
    }
  }
  std::vector<double> signal, time, noise;
  bool times_known = true;
  for (const Stamp& s : stamps) {
    times_known = times_known && std::isfinite(s.info.exptime_s) && s.info.exptime_s > 0;
    double total = 0.0, variance = 0.0;
    for (size_t q = 0; q < common.size(); ++q) {
      if (!common[q]) continue;
      total += s.electrons.data[q];
      variance += std::max(0.0, s.electrons.data[q]) + s.read_noise_e * s.read_noise_e;
    }
    signal.push_back(total);
    noise.push_back(std::sqrt(variance));
    time.push_back(s.info.exptime_s);
  }
  auto spread = [](const std::vector<double>& v) {
    const auto [lo, hi] = std::minmax_element(v.begin(), v.end());
    return *lo > 0 ? *hi / *lo - 1.0 : INFINITY;
  };
  // The comparison needs wings measured to better than a third of the 3 % tolerance.
  double worst = 0.0;
  for (size_t k = 0; k < signal.size(); ++k) {
    worst = std::max(worst, signal[k] > 0 ? noise[k] / signal[k] : INFINITY);
  }
  if (!(worst < kSameSignal / 3)) {
    const std::string which = "the light outside the spot's core, over the pixels measured in "
                              "every exposure, is too faint to compare their fluxes";
    if (times_known && spread(time) > kSameExptime) {
      *why = which + "; exposure times differ: a flux per exposure";
      return FluxMode::kPerExposure;
    }
    std::string cores;
    if (CoresShowDifferentLight(stamps, &cores)) {
      *why = which + "; " + cores + ": a flux per exposure";
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
      *why = times + ", the spot's wings proportional to them within " +
             Fmt(100 * spread(rate), 2) + " %: flux scaled by exposure time";
      return FluxMode::kExptimeScaled;
    }
    *why = times + ", the wings' signal per second differing by " + Fmt(100 * spread(rate), 2) +
           " % (shutter, lamp or nonlinearity): a flux per exposure";
    return FluxMode::kPerExposure;
  }
  if (signal_spread <= kSameSignal) {
    *why = std::string(times_known ? "one exposure time" : "no exposure times") +
           ", the spot's wings agree within " + Fmt(100 * signal_spread, 2) + " %: one shared flux";
    return FluxMode::kShared;
  }
  *why = std::string(times_known ? "one exposure time" : "no exposure times") +
         " but the spot's wings differ by " + Fmt(100 * signal_spread, 2) + " %: a flux per exposure";
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
        // A transient: this exposure differs at this pixel from what the others show there
        // (a big outlier may also pull the joint fit off the others, so they need not fit,
        // only agree). Where every exposure misfits (a wrong model, with z of tens),
        // sub-pixel shifts alone make them differ by several sd: the excess must also be
        // large against what the others show.
        std::vector<double> others;
        for (int j = 0; j < n; ++j) {
          if (j != k && q < z[j].size() && std::isfinite(z[j][q])) others.push_back(z[j][q]);
        }
        if (!others.empty()) {
          std::nth_element(others.begin(), others.begin() + others.size() / 2, others.end());
          const double typical = others[others.size() / 2];
          // The others' own spread (1.4826 MAD) says how much sub-pixel phase alone moves
          // this pixel's residual under the fitted model.
          std::vector<double> deviations;
          for (double o : others) deviations.push_back(std::fabs(o - typical));
          std::nth_element(deviations.begin(), deviations.begin() + deviations.size() / 2,
                           deviations.end());
          const double spread = 1.4826 * deviations[deviations.size() / 2];
          mask = std::fabs(z[k][q] - typical) >=
                 std::max({options.threshold_sd, options.transient_ratio * std::fabs(typical),
                           options.transient_spread * spread});
        }
      } else {
        // A spike: far above the other pixels at the same distance from the centre that are
        // not its neighbours (a spike drags the fit, which leaves its neighbours off too);
        // at least one, else there is nothing to compare with, as for the peak pixel.
        const double r = std::hypot(x - cx, y - cy);
        double ring = 0.0;
        int ring_pixels = 0;
        for (size_t p = 0; p < z[k].size(); ++p) {
          if (p == q || !std::isfinite(z[k][p])) continue;
          const int px = static_cast<int>(p % s.nx()), py = static_cast<int>(p / s.nx());
          if (std::max(std::abs(px - x), std::abs(py - y)) <= 1) continue;
          if (std::fabs(std::hypot(px - cx, py - cy) - r) >= 0.5) continue;
          ring = std::max(ring, std::fabs(z[k][p]));
          ++ring_pixels;
        }
        mask = ring_pixels >= 1 && std::fabs(z[k][q]) >= options.spike_ratio * ring;
      }
      if (mask) candidates.push_back({q, z[k][q]});
    }
    std::sort(candidates.begin(), candidates.end(),
              [](const Candidate& a, const Candidate& b) { return std::fabs(a.z) > std::fabs(b.z); });
    // One core pixel per exposure and round: a bad core pixel drags the fit, which leaves its
    // neighbours off too; they are judged again after the refit.
    int taken = 0, core_taken = 0;
    for (const Candidate& c : candidates) {
      if (taken >= options.max_per_exposure) break;
      const int x = static_cast<int>(c.q % s.nx()), y = static_cast<int>(c.q / s.nx());
      const bool core = std::hypot(x - cx, y - cy) <= options.core_radius_px;
      if (core && core_taken >= 1) continue;
      ++taken;
      core_taken += core;
      OutlierMask m;
      m.exposure = k;
      m.x_px = s.origin_x + x;
      m.y_px = s.origin_y + y;
      m.z = c.z;
      m.core = core;
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
  if (model_options.model.pixel_response_width != 1.0) {
    char w[32];
    std::snprintf(w, sizeof(w), "%.4g", model_options.model.pixel_response_width);
    out->notes.push_back("pixel response: each pixel collects from its central " + std::string(w) +
                         " px x " + w +
                         " px (pixel_response_width, held fixed: the intervals are "
                         "conditional on it)");
  }
  std::unique_ptr<FitModel> model = FitModel::Create(stamps, model_options, error);
  if (!model || !EffectsIdentifiable(*model, error)) return false;
  if (model->JitterReference() >= 0) {
    model_options.jitter_reference = model->JitterReference();  // kept by remade models
    out->notes.push_back(
        "jitter: jitter.var_*_px2.K is exposure K's jitter variance in excess "
        "of exposure " +
        std::to_string(model->JitterReference()) +
        "'s (the sharpest), whose own jitter is part of the CCD widths");
  }
  MapResult map;
  if (!FindMap(*model, options.config.fit.map, &map, error)) return false;

  // Outliers: mask, refit from where the MAP was, repeat. (The masked models are made from
  // model_options, so a Gaussian prior stays in their refits: gaussian_prior.h. FindOutliers
  // judges pixels by their residuals alone.)
  for (int round = 0; round < options.outliers.max_rounds; ++round) {
    const std::vector<OutlierMask> found = FindOutliers(*model, map.theta, options.outliers);
    if (found.empty()) break;
    const std::vector<Stamp> before = stamps;
    for (const OutlierMask& m : found) {
      Stamp& s = stamps[m.exposure];
      s.valid[static_cast<size_t>(m.y_px - s.origin_y) * s.nx() + (m.x_px - s.origin_x)] = 0;
    }
    std::string masked_error;
    std::unique_ptr<FitModel> masked = FitModel::Create(stamps, model_options, &masked_error);
    if (!masked) {
      // Masking ate a spot (a model far from one exposure, e.g. a flux shared across
      // exposures that differ, makes its whole core look deviant): keep the fit before this
      // round and say so, instead of failing the run.
      stamps = before;
      out->quality.Add("outlier_masking_stopped", Severity::kSuspect,
                       "outlier masking stopped after " + std::to_string(round) +
                           " round(s): masking the next " + std::to_string(found.size()) +
                           " pixel(s) would have left no spot to fit (" + masked_error +
                           "); the model misses these exposures as a whole, not a few pixels");
      break;
    }
    out->outliers.insert(out->outliers.end(), found.begin(), found.end());
    MapResult refit;
    std::string why;
    if (!RefineMap(*masked, map.theta, options.config.fit.map, &refit, &why) &&
        !FindMap(*masked, options.config.fit.map, &refit, error)) {
      return false;
    }
    model = std::move(masked);
    map = refit;
  }
  // The flux model was chosen with the outliers in the sums: choose again without them.
  if (!out->outliers.empty() && stamps.size() > 1 && !options.flux_given) {
    std::string why;
    const FluxMode again = ChooseFluxMode(stamps, &why);
    if (again != model_options.flux) {
      model_options.flux = again;
      out->notes.push_back("flux: " + ToString(again) + " after masking outliers (" + why + ")");
      std::unique_ptr<FitModel> remade = FitModel::Create(stamps, model_options, error);
      if (!remade) return false;
      if (!FindMap(*remade, options.config.fit.map, &map, error)) return false;
      model = std::move(remade);
    }
  }
  for (const OutlierMask& m : out->outliers) {
    const std::string text = "pixel (" + std::to_string(m.x_px) + ", " + std::to_string(m.y_px) +
                             ") stood z = " + Fmt(m.z, 3) + " from the model" +
                             (model->num_exposures() >= 3 ? " in this exposure alone"
                                                          : ", a lone spike") +
                             (m.z > 0 ? ": masked as a cosmic ray or hot pixel"
                                      : ": masked as a clipped, dead or cold pixel");
    if (m.core && model->num_exposures() < 3) {
      // One or two exposures: a lone spike in the core is the likeliest reading, not a sure one.
      out->quality.Add("core_outlier_masked", Severity::kSuspect,
                       text + " (in the spot's core, which carries the width)", m.exposure);
    } else if (m.core) {
      // In a set, the other exposures show the pixel as it should be.
      out->quality.Add("core_outlier_masked", Severity::kNote,
                       text + " (in the spot's core; the other exposures constrain it)",
                       m.exposure);
    } else {
      out->quality.Add("outlier_masked", Severity::kNote, text, m.exposure);
    }
  }

  // A peak far below the model: clipped, compressed, saturated without a known level, or a
  // PSF flatter at its core than the model (alone, these look alike; the outlier test does
  // not mask the peak pixel).
  {
    std::unique_ptr<FitEvaluator> ev = model->NewEvaluator();
    int short_peaks = 0;
    double worst = 0.0;
    for (int k = 0; k < model->num_exposures(); ++k) {
      const Stamp& s = model->stamps()[k];
      const int px = static_cast<int>(std::lround(map.theta[FitModel::XIndex(k)])) - s.origin_x;
      const int py = static_cast<int>(std::lround(map.theta[FitModel::YIndex(k)])) - s.origin_y;
      if (px < 0 || py < 0 || px >= s.nx() || py >= s.ny()) continue;
      const std::vector<double> z = Residuals(*model, ev.get(), map.theta.data(), k);
      const double zp = z[static_cast<size_t>(py) * s.nx() + px];
      if (std::isfinite(zp) && zp <= -options.outliers.threshold_sd) {
        ++short_peaks;
        worst = std::min(worst, zp);
      }
    }
    if (short_peaks > 0) {
      out->quality.Add("peak_deficit", Severity::kSuspect,
                       std::string("the peak pixel lies ") + Fmt(-worst, 3) +
                           " sd below the fitted model" +
                           (model->num_exposures() > 1
                                ? " in " + std::to_string(short_peaks) + " of " +
                                      std::to_string(model->num_exposures()) + " exposures"
                                : "") +
                           ": a clipped, compressed or saturated peak (give --saturation_adu "
                           "if the detector clips), or a core flatter than the model's");
    }
  }

  // No MCMC on a source already judged invalid (calibration found no compact spot, or a
  // masked peak; or the MAP's chi^2 is gross): its intervals would describe a model the data
  // reject, at the sampler's highest cost (a poorly fitting posterior mixes slowly).
  FitOptions fit_options = options.config.fit;
  if (fit_options.run_mcmc) {
    std::string invalid;
    for (const Exposure& e : exposures) {
      for (const Finding& f : e.report.quality.findings) {
        if (f.severity == Severity::kInvalid && invalid.empty()) invalid = f.message;
      }
    }
    for (const Finding& f : set_quality.findings) {
      if (f.severity == Severity::kInvalid && invalid.empty()) invalid = f.message;
    }
    if (invalid.empty() && map.dof >= 1 &&
        map.chi2 / map.dof > options.quality.gross_chi2_per_dof) {
      invalid = "chi2/dof = " + Fmt(map.chi2 / map.dof, 4) + " at the MAP";
    }
    if (!invalid.empty()) {
      fit_options.run_mcmc = false;
      out->quality.Add("mcmc_skipped", Severity::kNote,
                       "no MCMC: the source is already judged invalid (" + invalid +
                           "); the intervals are the Laplace approximation's");
    }
  }
  if (!RunFit(*model, fit_options, &out->result, error, &map)) return false;

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
  out->focus_points = FitEachFocusPosition(*model, options.config.fit.map);
  out->intensity_points = MeasureIntensityPoints(*model, out->result, options.config.fit.map);
  out->model = std::move(model);
  return true;
}

}  // namespace ccdpsf::fit
