// Calibration of a spot exposure. See exposure.h for the rules; this file holds the
// estimators and the reasons behind their constants.
#include "ccdpsf/exposure.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <utility>
#include <vector>

namespace ccdpsf {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Sigma clipping for the bias and read noise: 3 standard deviations keeps 99.73 % of
// Gaussian read noise while removing cosmic rays, hot pixels and the spot's far wings.
constexpr double kClipSigma = 3.0;
constexpr int kMaxClipRounds = 20;

// Fewer pixels than this cannot give a bias or a read noise worth using (the standard error
// of a standard deviation from n values is ~ 1/sqrt(2n), 22 % at n = 10).
constexpr int kMinNoisePixels = 10;

// Background pixels are those outside a box of half-size stamp_size around the spot. When
// fewer than this many remain the frame is "just a stamp", and the background is instead the
// pixels at least kStampFrameExclusionPx from the peak: at 6 px an Airy pattern of first dark
// ring 0.5 px (the paper's spots) holds ~1e-5 of its peak per pixel.
constexpr int kMinOutsideBoxPixels = 100;
constexpr double kStampFrameExclusionPx = 6.0;

// Spot finding smooths with a 3 x 3 box; a box needs this many valid pixels to count, so a
// lone valid pixel between masked ones cannot masquerade as a bright smoothed region.
constexpr int kMinValidInBox = 3;

// The centroid is the first moment in a (2 * kCentroidHalfWidth + 1)^2 box: 5 x 5 holds
// > 99 % of the paper's spots (total sigma ~ 0.5 px) while staying clear of neighbours.
constexpr int kCentroidHalfWidth = 2;

constexpr int kMinStampSize = 5;

std::string Format(const char* format, double a, double b) {
  char text[128];
  std::snprintf(text, sizeof(text), format, a, b);
  return text;
}

std::string FormatNumber(double value) {
  char text[64];
  std::snprintf(text, sizeof(text), "%g", value);
  return text;
}

// Header text as it may appear in a one-line message: control and non-ASCII bytes (which a
// corrupt file can hold) become '?'.
std::string Printable(std::string text) {
  for (char& c : text) {
    if (c < 0x20 || c > 0x7e) c = '?';
  }
  return text;
}

std::string ToUpper(std::string text) {
  for (char& c : text) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  return text;
}

bool HasKey(const FitsHeader& header, const std::string& name) {
  const std::string wanted = ToUpper(name);
  for (const FitsKey& key : header) {
    if (ToUpper(key.name) == wanted) return true;
  }
  return false;
}

// A number from the option if set, else from the keyword if present. A keyword that is
// present but not a number is an error: silently ignoring "GAIN = 'high'" would hide a
// broken header. Returns false with *error set in that case; *value stays empty when neither
// is given.
bool Resolve(const std::optional<double>& option, const FitsHeader& header, const char* keyword,
             std::optional<double>* value, std::string* source, std::string* error) {
  if (option) {
    *value = *option;
    *source = "option";
    return true;
  }
  if (!HasKey(header, keyword)) return true;
  const std::optional<double> number = FindNumber(header, keyword);
  if (!number) {
    *error = std::string("keyword ") + keyword + " is not a number";
    return false;
  }
  *value = *number;
  *source = std::string("keyword ") + keyword;
  return true;
}

double Median(std::vector<double> values) {
  const size_t n = values.size();
  const size_t mid = n / 2;
  std::nth_element(values.begin(), values.begin() + mid, values.end());
  const double upper = values[mid];
  if (n % 2 == 1) return upper;
  const double lower = *std::max_element(values.begin(), values.begin() + mid);
  return 0.5 * (lower + upper);
}

// Standard deviation, relative to the parent normal's, of a normal sample truncated to
// +-t standard deviations: sqrt(1 - 2 t phi(t) / (2 Phi(t) - 1)).
double TruncatedStdFactor(double t) {
  constexpr double kInvSqrt2Pi = 0.3989422804014327;
  const double phi = kInvSqrt2Pi * std::exp(-0.5 * t * t);
  const double mass = std::erf(t / std::sqrt(2.0));
  if (mass <= 0.0) return 1.0;
  return std::sqrt(std::max(0.0, 1.0 - 2.0 * t * phi / mass));
}

// Iterated clipping at +-k s, with s the clipped standard deviation itself, converges to
// s = u sigma where u solves u = TruncatedStdFactor(k u). Solved by fixed-point iteration,
// which contracts quickly because the factor varies slowly with t (u = 0.9848 for k = 3).
double ClippedStdFactor(double k) {
  double u = 1.0;
  for (int i = 0; i < 50; ++i) u = TruncatedStdFactor(k * u);
  return u > 0.0 ? u : 1.0;
}

// The frame being calibrated, with its mask.
struct Frame {
  const Image* adu = nullptr;
  std::vector<uint8_t> valid;
  int nx = 0;
  int ny = 0;

  bool Valid(int x, int y) const { return valid[static_cast<size_t>(y) * nx + x] != 0; }
  double At(int x, int y) const { return (*adu)(x, y); }
};

// Mean of the valid pixels in the 3 x 3 box centred on every pixel [ADU]; NaN where the box
// holds fewer than kMinValidInBox valid pixels. Box averaging raises a compact spot above
// single-pixel noise and hot pixels.
Image SmoothBox3(const Frame& frame) {
  Image smoothed(frame.nx, frame.ny, kNaN);
  for (int y = 0; y < frame.ny; ++y) {
    for (int x = 0; x < frame.nx; ++x) {
      double sum = 0.0;
      int count = 0;
      for (int dy = -1; dy <= 1; ++dy) {
        const int yy = y + dy;
        if (yy < 0 || yy >= frame.ny) continue;
        for (int dx = -1; dx <= 1; ++dx) {
          const int xx = x + dx;
          if (xx < 0 || xx >= frame.nx || !frame.Valid(xx, yy)) continue;
          sum += frame.At(xx, yy);
          ++count;
        }
      }
      if (count >= kMinValidInBox) smoothed(x, y) = sum / count;
    }
  }
  return smoothed;
}

// Indices (y * nx + x) of the valid pixels far from the peak: outside the box of half-size
// stamp_size around it, or, when that leaves fewer than kMinOutsideBoxPixels (the frame is
// little more than a stamp), at least kStampFrameExclusionPx away.
std::vector<size_t> BackgroundPixels(const Frame& frame, int peak_x, int peak_y, int stamp_size) {
  std::vector<size_t> outside_box;
  for (int y = 0; y < frame.ny; ++y) {
    for (int x = 0; x < frame.nx; ++x) {
      if (!frame.Valid(x, y)) continue;
      if (std::abs(x - peak_x) > stamp_size || std::abs(y - peak_y) > stamp_size) {
        outside_box.push_back(static_cast<size_t>(y) * frame.nx + x);
      }
    }
  }
  if (static_cast<int>(outside_box.size()) >= kMinOutsideBoxPixels) return outside_box;

  std::vector<size_t> far;
  const double min_distance2 = kStampFrameExclusionPx * kStampFrameExclusionPx;
  for (int y = 0; y < frame.ny; ++y) {
    for (int x = 0; x < frame.nx; ++x) {
      if (!frame.Valid(x, y)) continue;
      const double dx = x - peak_x;
      const double dy = y - peak_y;
      if (dx * dx + dy * dy >= min_distance2) far.push_back(static_cast<size_t>(y) * frame.nx + x);
    }
  }
  return far;
}

// Statistics of the pixels a bias or read noise is estimated from.
struct NoiseSample {
  ClippedStats stats;
  bool integer_valued = false;  // every value used is a whole number of ADU
  std::string source;           // for the report
};

std::optional<NoiseSample> MeasureNoise(const Frame& frame, const std::vector<size_t>& indices,
                                        const std::string& source) {
  std::vector<double> values;
  values.reserve(indices.size());
  bool integer_valued = true;
  for (size_t index : indices) {
    const double v = frame.adu->data[index];
    values.push_back(v);
    if (v != std::floor(v)) integer_valued = false;
  }
  if (static_cast<int>(values.size()) < kMinNoisePixels) return std::nullopt;
  std::optional<ClippedStats> stats = SigmaClippedStats(std::move(values), kClipSigma);
  if (!stats || stats->num_used < kMinNoisePixels) return std::nullopt;
  NoiseSample sample;
  sample.stats = *stats;
  sample.integer_valued = integer_valued;
  sample.source = source + " (" + std::to_string(stats->num_used) + " px)";
  return sample;
}

// Parses a positive decimal integer filling all of `text` (blanks aside).
std::optional<long> ParsePositiveInt(const std::string& text) {
  const size_t first = text.find_first_not_of(' ');
  if (first == std::string::npos) return std::nullopt;
  const size_t last = text.find_last_not_of(' ');
  const std::string digits = text.substr(first, last - first + 1);
  if (digits.empty() || digits.size() > 9) return std::nullopt;
  for (char c : digits) {
    if (!std::isdigit(static_cast<unsigned char>(c))) return std::nullopt;
  }
  return std::stol(digits);
}

// One axis of an IRAF section: "a:b", "a" or "*". Returns the 1-based inclusive range
// (first <= last) or nullopt if malformed.
std::optional<std::pair<long, long>> ParseAxis(const std::string& text, int size) {
  const size_t first = text.find_first_not_of(' ');
  if (first != std::string::npos && text[first] == '*' &&
      text.find_first_not_of(' ', first + 1) == std::string::npos) {
    return std::make_pair(1L, static_cast<long>(size));
  }
  const size_t colon = text.find(':');
  if (colon == std::string::npos) {
    const std::optional<long> n = ParsePositiveInt(text);
    if (!n) return std::nullopt;
    return std::make_pair(*n, *n);
  }
  const std::optional<long> a = ParsePositiveInt(text.substr(0, colon));
  const std::optional<long> b = ParsePositiveInt(text.substr(colon + 1));
  if (!a || !b) return std::nullopt;
  return std::make_pair(std::min(*a, *b), std::max(*a, *b));
}

}  // namespace

bool CalibrationOptions::IsValid(std::string* error) const {
  auto finite = [](const std::optional<double>& v) { return !v || std::isfinite(*v); };
  if (gain_e_per_adu && !(std::isfinite(*gain_e_per_adu) && *gain_e_per_adu > 0.0)) {
    *error = "gain_e_per_adu must be positive and finite, got " + FormatNumber(*gain_e_per_adu);
    return false;
  }
  if (read_noise_e && !(std::isfinite(*read_noise_e) && *read_noise_e >= 0.0)) {
    *error = "read_noise_e must be >= 0 and finite, got " + FormatNumber(*read_noise_e);
    return false;
  }
  if (!finite(bias_adu)) {
    *error = "bias_adu must be finite";
    return false;
  }
  // A saturation level of +infinity means "none"; NaN means nothing.
  if (saturation_adu && std::isnan(*saturation_adu)) {
    *error = "saturation_adu must be a number";
    return false;
  }
  if (wavelength_nm && !(std::isfinite(*wavelength_nm) && *wavelength_nm > 0.0)) {
    *error = "wavelength_nm must be positive and finite, got " + FormatNumber(*wavelength_nm);
    return false;
  }
  if (exptime_s && !(std::isfinite(*exptime_s) && *exptime_s >= 0.0)) {
    *error = "exptime_s must be >= 0 and finite, got " + FormatNumber(*exptime_s);
    return false;
  }
  if (pixel_um && !(std::isfinite(*pixel_um) && *pixel_um > 0.0)) {
    *error = "pixel_um must be positive and finite, got " + FormatNumber(*pixel_um);
    return false;
  }
  if (!finite(focus_position_um)) {
    *error = "focus_position_um must be finite";
    return false;
  }
  if (spot_x_px.has_value() != spot_y_px.has_value()) {
    *error = "give both spot_x_px and spot_y_px, or neither";
    return false;
  }
  if (!finite(spot_x_px) || !finite(spot_y_px)) {
    *error = "spot_x_px and spot_y_px must be finite";
    return false;
  }
  if (stamp_size < kMinStampSize) {
    *error = "stamp_size must be at least " + std::to_string(kMinStampSize) + ", got " +
             std::to_string(stamp_size);
    return false;
  }
  if (!(std::isfinite(min_peak_snr) && min_peak_snr >= 0.0)) {
    *error = "min_peak_snr must be >= 0 and finite, got " + FormatNumber(min_peak_snr);
    return false;
  }
  return true;
}

std::optional<ClippedStats> SigmaClippedStats(std::vector<double> values, double clip_sigma) {
  values.erase(
      std::remove_if(values.begin(), values.end(), [](double v) { return !std::isfinite(v); }),
      values.end());
  if (values.empty()) return std::nullopt;

  auto mean_and_std = [](const std::vector<double>& v, double* mean, double* std) {
    double sum = 0.0;
    for (double x : v) sum += x;
    *mean = sum / v.size();
    double sum2 = 0.0;
    for (double x : v) sum2 += (x - *mean) * (x - *mean);
    *std = v.size() > 1 ? std::sqrt(sum2 / (v.size() - 1)) : 0.0;
  };

  double mean = 0.0, std = 0.0;
  for (int round = 0; round < kMaxClipRounds; ++round) {
    mean_and_std(values, &mean, &std);
    if (std == 0.0) break;
    // Centre on the median: a few bright outliers pull the mean, not the median.
    const double centre = Median(values);
    const double limit = clip_sigma * std;
    std::vector<double> kept;
    kept.reserve(values.size());
    for (double v : values) {
      if (std::fabs(v - centre) <= limit) kept.push_back(v);
    }
    if (kept.size() == values.size() || kept.empty()) break;
    values = std::move(kept);
  }
  mean_and_std(values, &mean, &std);

  ClippedStats stats;
  stats.mean = mean;
  stats.median = Median(values);
  stats.stddev = std / ClippedStdFactor(clip_sigma);
  stats.num_used = static_cast<int>(values.size());
  return stats;
}

std::optional<PixelRegion> ParseIrafSection(const std::string& section, int nx, int ny,
                                            std::string* error) {
  const std::string quoted = "'" + Printable(section) + "'";
  const size_t open = section.find_first_not_of(' ');
  const size_t close = section.find_last_not_of(' ');
  const std::string malformed =
      quoted + " is malformed (expected an IRAF section such as [1:20,1:200])";
  if (open == std::string::npos || section[open] != '[' || section[close] != ']' || close <= open) {
    *error = malformed;
    return std::nullopt;
  }
  const std::string inner = section.substr(open + 1, close - open - 1);
  const size_t comma = inner.find(',');
  if (comma == std::string::npos || inner.find(',', comma + 1) != std::string::npos) {
    *error = malformed;
    return std::nullopt;
  }
  const auto x_range = ParseAxis(inner.substr(0, comma), nx);
  const auto y_range = ParseAxis(inner.substr(comma + 1), ny);
  if (!x_range || !y_range) {
    *error = malformed;
    return std::nullopt;
  }
  if (x_range->first < 1 || x_range->second > nx || y_range->first < 1 || y_range->second > ny) {
    *error = quoted + " is outside the " + std::to_string(nx) + "x" + std::to_string(ny) + " frame";
    return std::nullopt;
  }
  PixelRegion region;
  region.x_begin = static_cast<int>(x_range->first - 1);
  region.x_end = static_cast<int>(x_range->second);
  region.y_begin = static_cast<int>(y_range->first - 1);
  region.y_end = static_cast<int>(y_range->second);
  return region;
}

std::optional<Exposure> CalibrateExposure(const FitsImage& image, const std::string& source,
                                          const CalibrationOptions& options, std::string* error) {
  const std::string where = "'" + source + "': ";
  auto fail = [&](const std::string& message) {
    *error = where + message;
    return std::nullopt;
  };
  std::string problem;
  if (!options.IsValid(&problem)) return fail(problem);

  const Image& adu = image.pixels;
  if (adu.nx <= 0 || adu.ny <= 0 ||
      adu.data.size() != static_cast<size_t>(adu.nx) * static_cast<size_t>(adu.ny)) {
    return fail("image is empty or inconsistent (" + std::to_string(adu.nx) + " x " +
                std::to_string(adu.ny) + ", " + std::to_string(adu.data.size()) + " values)");
  }
  const FitsHeader& header = image.header;
  Exposure exposure;
  CalibrationReport& report = exposure.report;

  // Gain: it converts everything downstream, so there is no default.
  std::optional<double> gain;
  if (!Resolve(options.gain_e_per_adu, header, "GAIN", &gain, &report.gain_source, &problem)) {
    return fail(problem);
  }
  if (!gain) return fail("no gain: give --gain_e_per_adu or a GAIN keyword");
  if (!(std::isfinite(*gain) && *gain > 0.0)) {
    return fail("gain must be positive and finite, got " + FormatNumber(*gain) + " (" +
                report.gain_source + ")");
  }

  // Saturation and the mask.
  std::optional<double> saturation;
  if (!Resolve(options.saturation_adu, header, "SATURATE", &saturation, &report.saturation_source,
               &problem)) {
    return fail(problem);
  }
  if (!saturation) {
    saturation = std::numeric_limits<double>::infinity();
    report.saturation_source = "none";
  }
  if (std::isnan(*saturation)) return fail("saturation level is not a number");

  Frame frame;
  frame.adu = &adu;
  frame.nx = adu.nx;
  frame.ny = adu.ny;
  frame.valid.resize(adu.data.size());
  size_t num_valid = 0;
  for (size_t i = 0; i < adu.data.size(); ++i) {
    const double v = adu.data[i];
    frame.valid[i] = std::isfinite(v) && v < *saturation ? 1 : 0;
    num_valid += frame.valid[i];
  }
  if (num_valid == 0) {
    return fail("no usable pixels: all " + std::to_string(adu.data.size()) +
                " are non-finite or saturated");
  }

  // Where the spot is. Spot finding works on the raw frame: a constant bias moves every
  // smoothed value alike, so the brightest region does not depend on it.
  const bool position_given = options.spot_x_px.has_value();
  int peak_x = 0, peak_y = 0;
  double peak_smoothed = kNaN;
  Image smoothed;
  if (position_given) {
    const double x = *options.spot_x_px, y = *options.spot_y_px;
    // Pixel i covers [i - 0.5, i + 0.5); checked before rounding, which must not overflow.
    if (!(x >= -0.5 && x < frame.nx - 0.5 && y >= -0.5 && y < frame.ny - 0.5)) {
      return fail(Format("spot position (%.2f, %.2f) is outside the ", x, y) +
                  std::to_string(frame.nx) + "x" + std::to_string(frame.ny) + " frame");
    }
    peak_x = std::min(frame.nx - 1, static_cast<int>(std::floor(x + 0.5)));
    peak_y = std::min(frame.ny - 1, static_cast<int>(std::floor(y + 0.5)));
    report.spot_source = "option";
  } else {
    smoothed = SmoothBox3(frame);
    size_t best = smoothed.data.size();  // none yet
    for (size_t i = 0; i < smoothed.data.size(); ++i) {
      const double s = smoothed.data[i];
      if (std::isnan(s)) continue;
      if (best == smoothed.data.size() || s > smoothed.data[best]) best = i;
    }
    if (best == smoothed.data.size()) {
      return fail("no spot found: no 3x3 region has enough valid pixels");
    }
    const int box_x = static_cast<int>(best % frame.nx);
    const int box_y = static_cast<int>(best / frame.nx);
    peak_smoothed = smoothed.data[best];
    // The peak pixel is the brightest valid pixel of that box.
    double brightest = -std::numeric_limits<double>::infinity();
    for (int y = std::max(0, box_y - 1); y <= std::min(frame.ny - 1, box_y + 1); ++y) {
      for (int x = std::max(0, box_x - 1); x <= std::min(frame.nx - 1, box_x + 1); ++x) {
        if (frame.Valid(x, y) && frame.At(x, y) > brightest) {
          brightest = frame.At(x, y);
          peak_x = x;
          peak_y = y;
        }
      }
    }
    report.spot_source = "found";
  }

  // Bias and read noise, with the pixels they may be estimated from: the BIASSEC region if
  // the header names one, else the background far from the spot. Measured only if needed.
  std::optional<double> bias;
  if (!Resolve(options.bias_adu, header, "BIASLVL", &bias, &report.bias_source, &problem)) {
    return fail(problem);
  }
  std::optional<double> read_noise;
  if (!Resolve(options.read_noise_e, header, "RDNOISE", &read_noise, &report.read_noise_source,
               &problem)) {
    return fail(problem);
  }
  // The background is needed for the bias and read noise unless both are given, and for the
  // significance of a found spot.
  const std::vector<size_t> background_pixels =
      BackgroundPixels(frame, peak_x, peak_y, options.stamp_size);
  std::optional<NoiseSample> sample;
  if (!bias || !read_noise) {
    if (HasKey(header, "BIASSEC")) {
      const std::optional<std::string> section = FindString(header, "BIASSEC");
      if (!section) return fail("keyword BIASSEC is not a string");
      const std::optional<PixelRegion> region =
          ParseIrafSection(*section, frame.nx, frame.ny, &problem);
      if (!region) return fail("BIASSEC " + problem);
      std::vector<size_t> indices;
      for (int y = region->y_begin; y < region->y_end; ++y) {
        for (int x = region->x_begin; x < region->x_end; ++x) {
          if (frame.Valid(x, y)) indices.push_back(static_cast<size_t>(y) * frame.nx + x);
        }
      }
      sample = MeasureNoise(frame, indices, "BIASSEC " + Printable(*section));
      if (!sample) {
        return fail("BIASSEC " + Printable(*section) + " holds " + std::to_string(indices.size()) +
                    " valid pixels, too few for a bias or read noise (need " +
                    std::to_string(kMinNoisePixels) + ")");
      }
    } else {
      sample = MeasureNoise(frame, background_pixels, "sigma-clipped background");
      if (!sample) {
        return fail("too few background pixels (" + std::to_string(background_pixels.size()) +
                    ") to estimate the bias and read noise; give --bias_adu and "
                    "--read_noise_e, or BIASLVL and RDNOISE keywords");
      }
    }
    report.noise_rms_adu = sample->stats.stddev;
    report.noise_pixels = sample->stats.num_used;
  } else {
    report.noise_rms_adu = kNaN;
    report.noise_pixels = 0;
  }
  if (!bias) {
    bias = sample->stats.mean;
    report.bias_source = sample->source;
  }
  if (!read_noise) {
    // The measured variance includes the rounding of the signal to whole ADU, a uniform
    // error of variance 1/12 ADU^2 (Sheppard's correction; exact to ~exp(-2 pi^2 s^2) for a
    // noise s >= 0.5 ADU). The read noise of the noise model excludes it, so it is removed
    // when the data are quantised; if that would leave nothing (noise well below 1 ADU, where
    // the correction no longer holds) the variance is kept as measured.
    double variance_adu2 = sample->stats.stddev * sample->stats.stddev;
    if (sample->integer_valued && variance_adu2 - 1.0 / 12.0 > 0.0) variance_adu2 -= 1.0 / 12.0;
    read_noise = std::sqrt(variance_adu2) * *gain;
    report.read_noise_source = sample->source;
  }
  if (!std::isfinite(*bias)) return fail("bias level is not finite (" + report.bias_source + ")");
  if (!(std::isfinite(*read_noise) && *read_noise >= 0.0)) {
    return fail("read noise must be >= 0 and finite, got " + FormatNumber(*read_noise) + " (" +
                report.read_noise_source + ")");
  }

  // Significance of a found spot: the peak of the smoothed frame against the spread of the
  // smoothed background (which accounts for correlated noise), or, on a frame with too little
  // background, against the expected noise of a 3 x 3 mean: sqrt((RN/g)^2 + 1/12) / 3 ADU.
  if (!position_given) {
    double centre = *bias;
    double noise = std::sqrt((*read_noise / *gain) * (*read_noise / *gain) + 1.0 / 12.0) / 3.0;
    std::vector<double> background;
    for (size_t index : background_pixels) {
      if (!std::isnan(smoothed.data[index])) background.push_back(smoothed.data[index]);
    }
    if (static_cast<int>(background.size()) >= kMinNoisePixels) {
      const std::optional<ClippedStats> stats = SigmaClippedStats(background, kClipSigma);
      if (stats) {
        centre = stats->median;
        noise = stats->stddev;
      }
    }
    const double signal = peak_smoothed - centre;
    if (signal <= 0.0) {
      report.peak_snr = 0.0;
    } else if (noise <= 0.0) {
      report.peak_snr = std::numeric_limits<double>::infinity();  // a noiseless frame
    } else {
      report.peak_snr = signal / noise;
    }
    if (!(report.peak_snr >= options.min_peak_snr) || signal <= 0.0) {
      return fail(
          Format("no spot found: the brightest 3x3 region, at (%.0f, %.0f), is ", peak_x, peak_y) +
          Format("%.2f sigma above the background, need %g (min_peak_snr)", report.peak_snr,
                 options.min_peak_snr));
    }
  } else {
    report.peak_snr = kNaN;
  }

  // Centroid: flux-weighted first moment of the bias-subtracted valid pixels in the 5 x 5 box
  // around the peak. Negative (noise) values are kept, so that noise does not bias it.
  if (position_given) {
    report.spot_x_px = *options.spot_x_px;
    report.spot_y_px = *options.spot_y_px;
  } else {
    double sum = 0.0, sum_x = 0.0, sum_y = 0.0;
    for (int y = peak_y - kCentroidHalfWidth; y <= peak_y + kCentroidHalfWidth; ++y) {
      for (int x = peak_x - kCentroidHalfWidth; x <= peak_x + kCentroidHalfWidth; ++x) {
        if (x < 0 || y < 0 || x >= frame.nx || y >= frame.ny || !frame.Valid(x, y)) continue;
        const double w = frame.At(x, y) - *bias;
        sum += w;
        sum_x += w * x;
        sum_y += w * y;
      }
    }
    report.spot_x_px = sum > 0.0 ? sum_x / sum : peak_x;
    report.spot_y_px = sum > 0.0 ? sum_y / sum : peak_y;
  }
  report.peak_x_px = peak_x;
  report.peak_y_px = peak_y;
  report.peak_adu = frame.At(peak_x, peak_y);
  if (!std::isfinite(report.peak_adu)) report.peak_adu = kNaN;
  report.peak_e = frame.Valid(peak_x, peak_y) ? (report.peak_adu - *bias) * *gain : kNaN;

  // The stamp, with the peak pixel at index c = (n - 1) / 2 = int(n / 2 - 0.5).
  const int n = options.stamp_size;
  const int c = (n - 1) / 2;
  const int origin_x = peak_x - c;
  const int origin_y = peak_y - c;
  if (origin_x < 0 || origin_y < 0 || origin_x + n > frame.nx || origin_y + n > frame.ny) {
    return fail(Format("spot at (%.2f, %.2f) is too close to the frame edge for a ",
                       report.spot_x_px, report.spot_y_px) +
                std::to_string(n) + "x" + std::to_string(n) + " stamp (frame is " +
                std::to_string(frame.nx) + "x" + std::to_string(frame.ny) + ")");
  }

  Stamp& stamp = exposure.stamp;
  stamp.electrons = Image(n, n);
  stamp.valid.assign(static_cast<size_t>(n) * n, 0);
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const int x = origin_x + i, y = origin_y + j;
      const size_t k = static_cast<size_t>(j) * n + i;
      if (frame.Valid(x, y)) {
        stamp.electrons(i, j) = (frame.At(x, y) - *bias) * *gain;
        stamp.valid[k] = 1;
      }
      // A masked pixel keeps 0 e-: its value is meaningless, and 0 cannot poison a sum the
      // way NaN would.
    }
  }
  report.masked_pixels = n * n - stamp.NumValid();
  if (report.masked_pixels == n * n) {
    return fail("every pixel of the " + std::to_string(n) + "x" + std::to_string(n) +
                " stamp at (" + std::to_string(origin_x) + ", " + std::to_string(origin_y) +
                ") is masked (non-finite or saturated)");
  }
  stamp.origin_x = origin_x;
  stamp.origin_y = origin_y;
  stamp.gain_e_per_adu = *gain;
  stamp.read_noise_e = *read_noise;
  stamp.bias_adu = *bias;
  stamp.saturation_adu = *saturation;

  // Metadata for the fit and the trends.
  ExposureInfo& info = stamp.info;
  info.source = source;
  std::string ignored_source;
  std::optional<double> value;
  if (!Resolve(options.wavelength_nm, header, "WAVELEN", &value, &ignored_source, &problem)) {
    return fail(problem);
  }
  if (value) {
    if (!(std::isfinite(*value) && *value > 0.0)) {
      return fail("wavelength must be positive, got " + FormatNumber(*value));
    }
    info.wavelength_nm = *value;
  }
  value.reset();
  if (!Resolve(options.exptime_s, header, "EXPTIME", &value, &ignored_source, &problem)) {
    return fail(problem);
  }
  if (value) {
    if (!(std::isfinite(*value) && *value >= 0.0)) {
      return fail("exposure time must be >= 0, got " + FormatNumber(*value));
    }
    info.exptime_s = *value;
  }
  value.reset();
  if (!Resolve(options.pixel_um, header, "PIXSIZE", &value, &ignored_source, &problem)) {
    return fail(problem);
  }
  if (value) {
    if (!(std::isfinite(*value) && *value > 0.0)) {
      return fail("pixel size must be positive, got " + FormatNumber(*value));
    }
    info.pixel_um = *value;
  }
  value.reset();
  if (!Resolve(options.focus_position_um, header, "FOCUSPOS", &value, &ignored_source, &problem)) {
    return fail(problem);
  }
  if (value) {
    if (!std::isfinite(*value)) return fail("focus position is not finite");
    info.focus_position_um = *value;
  }
  return exposure;
}

std::optional<Exposure> LoadExposure(const std::string& path, const CalibrationOptions& options,
                                     std::string* error) {
  const std::optional<FitsImage> image = ReadFitsImage(path, error);
  if (!image) return std::nullopt;
  return CalibrateExposure(*image, path, options, error);
}

}  // namespace ccdpsf
