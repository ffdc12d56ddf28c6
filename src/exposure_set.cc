// Sets of exposures (exposure_set.h).
#include "ccdpsf/exposure_set.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <numeric>

#include "internal/fnv1a.h"

namespace ccdpsf {
namespace {

namespace fs = std::filesystem;

// A fingerprint of a stamp's recorded pixels (FNV-1a over the electrons' bytes and the
// stamp's place), to tell the same exposure under two names.
uint64_t Fingerprint(const Stamp& s) {
  internal::Fnv1a h;
  h.Add(s.electrons.data.data(), s.electrons.data.size() * sizeof(double));
  h.Add(&s.origin_x, sizeof(s.origin_x));
  h.Add(&s.origin_y, sizeof(s.origin_y));
  return h.value();
}

}  // namespace

std::string CanonicalPath(const std::string& path) {
  std::error_code ec;
  const fs::path c = fs::weakly_canonical(fs::path(path), ec);
  return ec ? path : c.string();
}

std::string CountedTwice(const std::string& path, const std::string& earlier, bool same_file) {
  return same_file ? "'" + path + "' is given twice (as '" + earlier +
                         "' too): each exposure must count once"
                   : "'" + path + "' and '" + earlier +
                         "' hold identical pixels: the same exposure under two names counts once";
}

namespace {

// Peak pixel, scaled to a spot centred on it (below), and 5 x 5 box around the stamp's
// centre [e-]; false if the box has a masked or saturated (censored from above) pixel, where
// the fraction means nothing, or the peak is no peak. Pixels censored
// from below (a clipped black level) count at their level, next to nothing.
bool PeakAndBox(const Stamp& s, double* peak, double* box) {
  const int c = (s.nx() - 1) / 2;
  *peak = 0.0;
  *box = 0.0;
  for (int j = c - 2; j <= c + 2; ++j) {
    for (int i = c - 2; i <= c + 2; ++i) {
      if (i < 0 || j < 0 || i >= s.nx() || j >= s.ny()) return false;
      const size_t q = static_cast<size_t>(j) * s.nx() + i;
      if (!s.valid[q] || s.CensorAt(q) == Censor::kAtOrAbove) return false;
      *box += s.electrons.data[q];
      if (i == c && j == c) *peak = s.electrons.data[q];
    }
  }
  if (!(*box > 0.0 && *peak > 0.0)) return false;
  // The peak pixel's share depends on where in it the spot's centre falls (by up to 1.9x
  // from centre to corner for a 0.55 px Gaussian). A parabola through the logarithms of the
  // peak and its two neighbours on each axis gives the centre's offset u and the curvature
  // 1 / s^2 of a sampled Gaussian, whose peak sample is exp(-u^2 / 2 s^2) of its value at
  // u = 0; the share is scaled back to u = 0 (measured on photon-shot spots at offsets up to
  // 0.49 px: the corrected shares agree within 2 %, the raw ones differ by 15 %).
  double scale = 1.0;
  for (const auto& [di, dj] : {std::pair<int, int>{1, 0}, std::pair<int, int>{0, 1}}) {
    const double lo = s.electrons(c - di, c - dj), hi = s.electrons(c + di, c + dj);
    if (!(lo > 0.0 && hi > 0.0)) return false;
    const double l0 = std::log(*peak), lm = std::log(lo), lp = std::log(hi);
    const double curvature = 2 * l0 - lm - lp;  // 1 / s^2
    if (!(curvature > 0.0)) return false;
    const double u = 0.5 * (lp - lm) / curvature;
    if (!(std::abs(u) <= 1.0)) return false;
    scale *= std::exp(-0.5 * u * u * curvature);
  }
  *peak /= scale;
  return true;
}

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

// Thresholds of the compression check (exposure_set.h).
constexpr double kMinSignalSpan = 1.5;
constexpr double kMinBrighter = 1.3;
constexpr double kMinDeficit = 0.03;
constexpr double kDeficitSd = 3.0;
// The spot's light per second may differ by this fraction (lamp drift) for the exposures to
// count as one intensity scaled by exposure time.
constexpr double kTimeScaledTolerance = 0.15;

// The check on the exposures `members` (one focus position).
void CheckPeakCompressionAtOneFocus(const std::vector<Exposure>& exposures,
                                    const std::vector<int>& members, Severity severity,
                                    const std::string& modelled, Quality* quality) {
  struct Point {
    int index;
    double peak, box, fraction, exptime;
  };
  std::vector<Point> points;
  for (int k : members) {
    double peak = 0, box = 0;
    if (!PeakAndBox(exposures[k].stamp, &peak, &box)) continue;
    points.push_back({static_cast<int>(k), peak, box, peak / box,
                      exposures[k].stamp.info.exptime_s});
  }
  if (points.size() < 3) return;
  std::sort(points.begin(), points.end(), [](const Point& a, const Point& b) { return a.box < b.box; });
  if (points.back().box < kMinSignalSpan * points.front().box) return;
  const size_t reference = std::max<size_t>(2, points.size() / 3);
  std::vector<double> fractions;
  double ref_box = 0.0;
  for (size_t i = 0; i < reference; ++i) {
    fractions.push_back(points[i].fraction);
    ref_box = std::max(ref_box, points[i].box);
  }
  const double f_ref = Median(fractions);
  // Counting noise of a fraction f of B electrons: sqrt(f (1 - f) / B); the reference is a
  // median of `reference` of them (variance pi/2 / n of one, for a median of normals).
  double ref_var = 0.0;
  for (size_t i = 0; i < reference; ++i) ref_var += f_ref * (1 - f_ref) / points[i].box;
  ref_var = (M_PI / 2) * ref_var / (reference * static_cast<double>(reference));
  // The line through the reference peaks against exposure time, where it is known.
  double st = 0, sp = 0;
  bool have_time = true;
  for (size_t i = 0; i < reference; ++i) {
    have_time = have_time && std::isfinite(points[i].exptime) && points[i].exptime > 0;
    st += points[i].exptime * points[i].exptime;
    sp += points[i].exptime * points[i].peak;
  }
  const double rate = have_time && st > 0 ? sp / st : NAN;
  // The same for the spot's total light: the peak line only means something where the
  // intensity was varied through the exposure time (the light per second stays put).
  double sb = 0;
  for (size_t i = 0; i < reference; ++i) sb += points[i].exptime * points[i].box;
  const double box_rate = have_time && st > 0 ? sb / st : NAN;
  for (size_t i = reference; i < points.size(); ++i) {
    const Point& p = points[i];
    if (p.box < kMinBrighter * ref_box) continue;
    const double deficit = 1.0 - p.fraction / f_ref;
    const double sd =
        std::sqrt(p.fraction * (1 - p.fraction) / p.box + ref_var) / f_ref;
    if (!(deficit > kMinDeficit && deficit > kDeficitSd * sd)) continue;
    char text[400];
    int used = std::snprintf(text, sizeof(text),
                             "the peak pixel holds %.1f %% less of the spot's light than in the "
                             "faintest exposures (%.3f against %.3f centred, %.1f sd): compressed "
                             "before saturation, or a core that broadens with the signal "
                             "(brighter-fatter)",
                             100 * deficit, p.fraction, f_ref, deficit / sd);
    const bool time_scaled = std::isfinite(box_rate) && std::isfinite(p.exptime) &&
                             p.exptime > 0 &&
                             std::abs(p.box / (box_rate * p.exptime) - 1.0) < kTimeScaledTolerance;
    if (std::isfinite(rate) && time_scaled && used > 0 && used < 380) {
      std::snprintf(text + used, sizeof(text) - used,
                    "; it lies %.1f %% below the line through their peaks against exposure time",
                    100 * (1 - p.peak / (rate * p.exptime)));
    }
    std::string message = text;
    if (severity == Severity::kNote) message += "; " + modelled;
    quality->Add("compressed_peak", severity, message, p.index);
  }
}

}  // namespace

void CheckPeakCompression(const std::vector<Exposure>& exposures, Quality* quality,
                          const std::string& modelled) {
  // A defocused spot holds less of its light in its peak pixel: only exposures at one focus
  // position (FOCUSPOS, or none) are compared.
  std::vector<std::vector<int>> groups;
  std::vector<double> focus;
  for (size_t k = 0; k < exposures.size(); ++k) {
    const double z = exposures[k].stamp.info.focus_position_um;
    size_t g = 0;
    while (g < focus.size() && !(focus[g] == z || (std::isnan(focus[g]) && std::isnan(z)))) ++g;
    if (g == focus.size()) {
      focus.push_back(z);
      groups.emplace_back();
    }
    groups[g].push_back(static_cast<int>(k));
  }
  const Severity severity = modelled.empty() ? Severity::kSuspect : Severity::kNote;
  for (const std::vector<int>& members : groups) {
    CheckPeakCompressionAtOneFocus(exposures, members, severity, modelled, quality);
  }
}

bool LoadExposureSet(const std::vector<InputFile>& inputs, const ExposureSetOptions& options,
                     ExposureSet* set, std::string* error) {
  *set = ExposureSet();
  if (inputs.empty()) {
    *error = "no exposures to read";
    return false;
  }
  std::vector<std::pair<std::string, std::string>> keys;  // (canonical path, hdu)
  std::vector<uint64_t> prints;
  for (const InputFile& input : inputs) {
    std::optional<Exposure> e = LoadExposure(input.path, input.options, error);
    if (!e) return false;
    const auto hdu = e->report.metadata.find("hdu");
    const std::pair<std::string, std::string> key = {
        CanonicalPath(input.path), hdu == e->report.metadata.end() ? "" : hdu->second.text};
    const uint64_t print = Fingerprint(e->stamp);
    for (size_t k = 0; k < keys.size(); ++k) {
      if (keys[k] == key || prints[k] == print) {
        *error = CountedTwice(input.path, inputs[k].path, keys[k] == key);
        return false;
      }
    }
    if (options.require_pixel_size && !std::isfinite(e->stamp.info.pixel_um)) {
      *error = "'" + input.path +
               "': no pixel size: give --pixel_um, a manifest column pixel_um or a PIXSIZE "
               "keyword (--keywords maps another name); the metrics are in um";
      return false;
    }
    keys.push_back(key);
    prints.push_back(print);
    set->exposures.push_back(std::move(*e));
    set->settings.push_back(input.setting);
  }
  // Mixed wavelengths do not share one PSF.
  if (!options.allow_mixed_wavelengths) {
    for (size_t k = 1; k < set->exposures.size(); ++k) {
      const double a = set->exposures[0].stamp.info.wavelength_nm;
      const double b = set->exposures[k].stamp.info.wavelength_nm;
      if (std::isfinite(a) && std::isfinite(b) && std::fabs(a - b) > 1.0) {
        char text[160];
        std::snprintf(text, sizeof(text), " are at %g nm and %g nm", a, b);
        *error = "'" + inputs[0].path + "' and '" + inputs[k].path + "'" + text +
                 ": one PSF cannot describe both (fit them separately, or pass "
                 "--mixed_wavelengths to share it anyway)";
        return false;
      }
    }
  }
  CheckPeakCompression(set->exposures, &set->quality, options.compression_modelled);
  return true;
}

}  // namespace ccdpsf
