// Calibration of a spot exposure. See exposure.h for the rules; this file holds the
// estimators and the reasons behind their constants.
#include "ccdpsf/exposure.h"

#include <algorithm>
#include <cctype>
#include <cstdarg>
#include <climits>
#include <cstdint>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "internal/text.h"

namespace ccdpsf {
namespace {

using internal::Printable;

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

// The centroid is the first moment in a (2 * kCentroidHalfWidth + 1)^2 box: 5 x 5 holds
// > 99 % of the paper's spots (total sigma ~ 0.5 px) while staying clear of neighbours.
constexpr int kCentroidHalfWidth = 2;

constexpr int kMinStampSize = 5;

// snprintf into a std::string (messages are short; longer ones are cut, never overrun).
__attribute__((format(printf, 1, 2))) std::string Format(const char* format, ...) {
  char text[512];
  va_list args;
  va_start(args, format);
  std::vsnprintf(text, sizeof(text), format, args);
  va_end(args);
  return text;
}

std::string FormatNumber(double value) {
  char text[64];
  std::snprintf(text, sizeof(text), "%g", value);
  return text;
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

namespace {

// ---------------------------------------------------------------------------------------
// The frame being calibrated.

struct Frame {
  const Image* adu = nullptr;
  std::vector<uint8_t> valid;  // finite and not flagged by a bad-pixel mask
  PixelRegion region;          // the data section
  int nx = 0;
  int ny = 0;

  bool Valid(int x, int y) const { return valid[static_cast<size_t>(y) * nx + x] != 0; }
  double At(int x, int y) const { return (*adu)(x, y); }
};

// Indices (y * nx + x) of the valid pixels of the data section far from the peak: outside
// the box of half-size stamp_size around it, or, when that leaves fewer than
// kMinOutsideBoxPixels (the frame is little more than a stamp), at least
// kStampFrameExclusionPx away.
std::vector<size_t> BackgroundPixels(const Frame& frame, int peak_x, int peak_y, int stamp_size) {
  const PixelRegion& r = frame.region;
  std::vector<size_t> outside_box;
  for (int y = r.y_begin; y < r.y_end; ++y) {
    for (int x = r.x_begin; x < r.x_end; ++x) {
      if (!frame.Valid(x, y)) continue;
      if (std::abs(x - peak_x) > stamp_size || std::abs(y - peak_y) > stamp_size) {
        outside_box.push_back(static_cast<size_t>(y) * frame.nx + x);
      }
    }
  }
  if (static_cast<int>(outside_box.size()) >= kMinOutsideBoxPixels) return outside_box;
  std::vector<size_t> far;
  const double min_distance2 = kStampFrameExclusionPx * kStampFrameExclusionPx;
  for (int y = r.y_begin; y < r.y_end; ++y) {
    for (int x = r.x_begin; x < r.x_end; ++x) {
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
  double minimum = 0.0;         // smallest value of the sample [ADU]
  double at_minimum = 0.0;      // fraction of the sample at exactly that value
  std::string source;           // for the report
};

std::optional<NoiseSample> MeasureNoise(const Image& adu, const std::vector<size_t>& indices,
                                        const std::string& source) {
  std::vector<double> values;
  values.reserve(indices.size());
  bool integer_valued = true;
  double minimum = INFINITY;
  for (size_t index : indices) {
    const double v = adu.data[index];
    values.push_back(v);
    if (v != std::floor(v)) integer_valued = false;
    minimum = std::min(minimum, v);
  }
  if (static_cast<int>(values.size()) < kMinNoisePixels) return std::nullopt;
  size_t at_minimum = 0;
  for (double v : values) at_minimum += v == minimum;
  const double fraction = static_cast<double>(at_minimum) / values.size();
  std::optional<ClippedStats> stats = SigmaClippedStats(std::move(values), kClipSigma);
  if (!stats || stats->num_used < kMinNoisePixels) return std::nullopt;
  NoiseSample sample;
  sample.stats = *stats;
  sample.integer_valued = integer_valued;
  sample.minimum = minimum;
  sample.at_minimum = fraction;
  sample.source = source + " (" + std::to_string(stats->num_used) + " px)";
  return sample;
}

// A background clipped at the black level: this many of its pixels at exactly its minimum.
// Unclipped noise of sd >= 0.5 ADU puts at most ~16 % of the pixels in its lowest occupied
// ADU bin (at sd < 0.5 ADU the spread check below refuses the read noise anyway).
constexpr double kClippedAtMinimum = 0.2;
// A read noise estimated from a spread below this [ADU] is the ADC's rounding, not noise.
constexpr double kMinEstimableSpreadAdu = 0.5;

// A black-level clip below the ADC's range: >= 1 % of the data section (and >= 10 pixels)
// at exactly the frame's minimum value.
constexpr double kFloorFraction = 0.01;
constexpr int kMinFloorPixels = 10;

// Core of the spot for masking and censoring findings: within 1.5 px of the peak pixel,
// i.e. the 3 x 3 box and its four side neighbours at distance 1... 1.41 (the 3 x 3 box).
constexpr double kCoreRadiusPx = 1.5;

// Other sources in the stamp (contamination.h): significance, the closest distance looked
// at, and the protected core around the spot.
constexpr double kSourceSignificance = 7.0;
constexpr double kSourceMinDistancePx = 3.0;
constexpr double kSourceProtectPx = 2.5;
// Column defects: significance in robust sds of the column-to-neighbours differences.
constexpr double kColumnSignificance = 6.0;
// On a frame with too few rows clear of the stamp, the rows more than this from the spot's
// peak row [px] judge the columns (a 21-row frame keeps 14).
constexpr int kColumnRowsFromSpot = 3;
// A clipped top: tied maximal pixels must stand this many pixel sds above the background.
constexpr double kFlatTopSignificance = 20.0;
// A peak this close to the ADC's full scale with no saturation level known may be compressed.
constexpr double kNearFullScale = 0.9;
// Spot finding looks at no more than this many background pixels for its statistics.
constexpr size_t kMaxStatPixels = 200000;

std::string SectionText(const PixelRegion& r) {
  char text[96];
  std::snprintf(text, sizeof(text), "[%d:%d,%d:%d]", r.x_begin + 1, r.x_end, r.y_begin + 1,
                r.y_end);
  return text;
}

// "frame edge", or the data section's edge when it is not the whole frame, for messages.
std::string EdgeName(const Frame& frame) {
  const PixelRegion& r = frame.region;
  if (r.x_begin == 0 && r.y_begin == 0 && r.x_end == frame.nx && r.y_end == frame.ny) {
    return "frame edge";
  }
  return "edge of the data section " + SectionText(r);
}

// Clipped statistics of a regular subsample of the valid values of `image` in `region`.
std::optional<ClippedStats> RegionStats(const Image& image, const std::vector<uint8_t>& valid,
                                        const PixelRegion& region) {
  const size_t total = static_cast<size_t>(region.Width()) * region.Height();
  const size_t stride = std::max<size_t>(1, total / kMaxStatPixels);
  std::vector<double> values;
  size_t i = 0;
  for (int y = region.y_begin; y < region.y_end; ++y) {
    for (int x = region.x_begin; x < region.x_end; ++x, ++i) {
      if (i % stride != 0) continue;
      const size_t k = static_cast<size_t>(y) * image.nx + x;
      if (valid[k] && std::isfinite(image.data[k])) values.push_back(image.data[k]);
    }
  }
  return SigmaClippedStats(std::move(values), kClipSigma);
}

}  // namespace

// ---------------------------------------------------------------------------------------

void CalibrationOptions::Set(const std::string& quantity, double value, const std::string& source) {
  given.SetNumber(quantity, value, source);
}

void CalibrationOptions::SetText(const std::string& quantity, const std::string& value,
                                 const std::string& source) {
  given.SetText(quantity, value, source);
}

bool CalibrationOptions::IsValid(std::string* error) const {
  auto number = [&](const char* q) -> std::optional<double> {
    const GivenValue* v = given.Find(q);
    if (v == nullptr || !v->number) return std::nullopt;
    return *v->number;
  };
  // " (flag --x)" after a message about a given value.
  auto from = [&](const std::string& q) {
    const GivenValue* v = given.Find(q);
    return v == nullptr || v->source.empty() ? std::string() : " (" + v->source + ")";
  };
  for (const std::string& q : MetadataQuantities()) {
    const std::optional<double> v = number(q.c_str());
    if (v && !CheckQuantityValue(q, *v, error)) {
      *error += from(q);
      return false;
    }
  }
  if (given.Has("spot_x_px") != given.Has("spot_y_px")) {
    *error = "give both spot_x_px and spot_y_px, or neither";
    return false;
  }
  for (const char* q : {"bias_section", "data_section", "search_region"}) {
    const GivenValue* v = given.Find(q);
    if (v == nullptr || !v->text) continue;
    std::string why;
    // Syntax only: the frame's size is not known yet.
    if (!ParseIrafSection(*v->text, INT_MAX / 2, INT_MAX / 2, &why)) {
      *error = std::string(q) + " " + why + from(q);
      return false;
    }
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

std::string CalibrationReport::Source(const std::string& quantity) const {
  const auto it = metadata.find(quantity);
  return it == metadata.end() ? "unknown" : it->second.source;
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
                                          const CalibrationOptions& options, std::string* error,
                                          const Image* bad_pixels) {
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
  const GivenMetadata& given = options.given;
  const KeywordMap& keywords = options.keywords;
  Exposure exposure;
  CalibrationReport& report = exposure.report;
  MetadataRecord& record = report.metadata;
  auto note_number = [&](const std::string& q, double value, const std::string& from) {
    MetadataEntry& e = record[q];
    e.number = value;
    e.text.clear();
    e.source = from;
  };
  auto note_text = [&](const std::string& q, const std::string& value, const std::string& from) {
    MetadataEntry& e = record[q];
    e.number = kNaN;
    e.text = value;
    e.source = from;
  };
  auto given_source = [&](const std::string& q) {
    const GivenValue* v = given.Find(q);
    return v == nullptr || v->source.empty() ? std::string("option") : v->source;
  };
  {
    const std::string hdu = image.extname.empty() ? std::to_string(image.hdu - 1) : image.extname;
    note_text("hdu", hdu,
              given.Has("hdu") ? given_source("hdu")
                               : (image.hdu == 1 ? "default (primary HDU)"
                                                 : "default (first image extension)"));
  }
  if (const GivenValue* m = given.Find("bad_pixel_mask"); m != nullptr && m->text) {
    note_text("bad_pixel_mask", *m->text, given_source("bad_pixel_mask"));
  }

  // Gain: it converts everything downstream, so there is no default.
  std::optional<double> gain;
  std::string from;
  if (!ResolveNumber(given, keywords, header, "gain_e_per_adu", &gain, &from, &problem)) {
    return fail(problem);
  }
  if (!gain) {
    return fail("no gain: give --gain_e_per_adu, a manifest column gain_e_per_adu or a GAIN "
                "keyword");
  }
  if (!(std::isfinite(*gain) && *gain > 0.0)) {
    return fail("gain must be positive and finite, got " + FormatNumber(*gain) + " (" + from + ")");
  }
  note_number("gain_e_per_adu", *gain, from);

  // The data section: where the light-sensitive pixels are (a test stand's segment also
  // holds its overscan). Spot, background and stamp all stay inside it.
  Frame frame;
  frame.adu = &adu;
  frame.nx = adu.nx;
  frame.ny = adu.ny;
  frame.region = {0, adu.nx, 0, adu.ny};
  {
    std::optional<std::string> section;
    if (!ResolveText(given, keywords, header, "data_section", &section, &from, &problem)) {
      return fail(problem);
    }
    if (section) {
      const std::optional<PixelRegion> r = ParseIrafSection(*section, adu.nx, adu.ny, &problem);
      if (!r) return fail("data section (" + from + ") " + problem);
      frame.region = *r;
      note_text("data_section", Printable(*section), from);
    } else {
      note_text("data_section", SectionText(frame.region), "whole image");
    }
  }
  PixelRegion search = frame.region;
  if (const GivenValue* s = given.Find("search_region"); s != nullptr && s->text) {
    const std::optional<PixelRegion> r = ParseIrafSection(*s->text, adu.nx, adu.ny, &problem);
    if (!r) return fail("search region " + problem);
    search.x_begin = std::max(search.x_begin, r->x_begin);
    search.x_end = std::min(search.x_end, r->x_end);
    search.y_begin = std::max(search.y_begin, r->y_begin);
    search.y_end = std::min(search.y_end, r->y_end);
    if (search.x_begin >= search.x_end || search.y_begin >= search.y_end) {
      return fail("search region " + Printable(*s->text) + " lies outside the data section " +
                  SectionText(frame.region));
    }
    note_text("search_region", Printable(*s->text), given_source("search_region"));
  }

  // The mask: non-finite pixels and the user's bad pixels.
  if (bad_pixels != nullptr && (bad_pixels->nx != adu.nx || bad_pixels->ny != adu.ny)) {
    return fail("the bad-pixel mask is " + std::to_string(bad_pixels->nx) + "x" +
                std::to_string(bad_pixels->ny) + ", the image " + std::to_string(adu.nx) + "x" +
                std::to_string(adu.ny));
  }
  frame.valid.resize(adu.data.size());
  size_t num_valid = 0;
  std::vector<uint8_t> user_bad(bad_pixels != nullptr ? adu.data.size() : 0, 0);
  for (size_t i = 0; i < adu.data.size(); ++i) {
    const bool bad = bad_pixels != nullptr && bad_pixels->data[i] != 0.0;
    if (bad) user_bad[i] = 1;
    frame.valid[i] = std::isfinite(adu.data[i]) && !bad ? 1 : 0;
    num_valid += frame.valid[i];
  }
  if (num_valid == 0) {
    return fail("no usable pixels: all " + std::to_string(adu.data.size()) +
                " are non-finite or flagged bad");
  }

  // Saturation and the ADC's range: the levels beyond which a pixel is censored.
  std::optional<double> saturation;
  if (!ResolveNumber(given, keywords, header, "saturation_adu", &saturation, &from, &problem)) {
    return fail(problem);
  }
  bool integer_data = true;
  for (int y = frame.region.y_begin; y < frame.region.y_end && integer_data; ++y) {
    for (int x = frame.region.x_begin; x < frame.region.x_end; ++x) {
      const double v = adu(x, y);
      if (std::isfinite(v) && v != std::floor(v)) {
        integer_data = false;
        break;
      }
    }
  }
  if (saturation) {
    report.ceiling_adu = *saturation;
    report.ceiling_source = from;
    note_number("saturation_adu", *saturation, from);
  } else {
    note_number("saturation_adu", kNaN, "unknown");
  }
  if (std::isfinite(image.adc_max) && image.adc_max < report.ceiling_adu) {
    report.ceiling_adu = image.adc_max;
    report.ceiling_source = "ADC range (BITPIX " + std::to_string(image.bitpix) + ")";
  }
  {
    // A black-level clip: many pixels at exactly the frame's minimum.
    double minimum = INFINITY;
    size_t count = 0, total = 0;
    for (int y = frame.region.y_begin; y < frame.region.y_end; ++y) {
      for (int x = frame.region.x_begin; x < frame.region.x_end; ++x) {
        if (!frame.Valid(x, y)) continue;
        const double v = adu(x, y);
        ++total;
        if (v < minimum) {
          minimum = v;
          count = 1;
        } else if (v == minimum) {
          ++count;
        }
      }
    }
    const double fraction = total > 0 ? static_cast<double>(count) / total : 0.0;
    if (integer_data && static_cast<int>(count) >= kMinFloorPixels && fraction >= kFloorFraction) {
      report.floor_adu = minimum;
      char text[160];
      std::snprintf(text, sizeof(text),
                    "detected: %.1f %% of the data section sits at exactly %g ADU, its minimum",
                    100.0 * fraction, minimum);
      report.floor_source = text;
    } else if (std::isfinite(image.adc_min)) {
      report.floor_adu = image.adc_min;
      report.floor_source = "ADC range (BITPIX " + std::to_string(image.bitpix) + ")";
    }
  }

  // Statistics of the data section for spot finding: the background level and the spread
  // of single pixels and of 3 x 3 means. Integer data always carry the ADC's rounding,
  // 1/12 ADU^2, even where the recorded background is flat (a clipped black level).
  const Image smoothed = SmoothBox3(adu, frame.valid, search);
  double background = 0.0, pixel_sd = 0.0, smoothed_sd = 0.0;
  {
    const std::optional<ClippedStats> raw = RegionStats(adu, frame.valid, search);
    if (!raw) return fail("no usable pixels in the data section " + SectionText(frame.region));
    std::vector<uint8_t> all(adu.data.size(), 1);
    const std::optional<ClippedStats> smooth = RegionStats(smoothed, all, search);
    background = raw->median;
    const double rounding = integer_data ? std::sqrt(1.0 / 12.0) : 0.0;
    pixel_sd = std::max(raw->stddev, rounding);
    smoothed_sd = std::max(smooth ? smooth->stddev : 0.0, rounding / 3.0);
    report.background_adu = background;
    report.background_sd_adu = pixel_sd;
  }

  // Where the spot is.
  SpotFinderOptions finder;
  finder.min_significance = options.min_peak_snr;
  finder.stamp_size = options.stamp_size;
  const bool position_given = given.Has("spot_x_px");
  int peak_x = 0, peak_y = 0;
  if (position_given) {
    std::optional<double> x, y;
    ResolveNumber(given, keywords, header, "spot_x_px", &x, &from, &problem);
    report.spot_source = from;
    ResolveNumber(given, keywords, header, "spot_y_px", &y, &from, &problem);
    // Pixel i covers [i - 0.5, i + 0.5); checked before rounding, which must not overflow.
    if (!(*x >= frame.region.x_begin - 0.5 && *x < frame.region.x_end - 0.5 &&
          *y >= frame.region.y_begin - 0.5 && *y < frame.region.y_end - 0.5)) {
      return fail(Format("spot position (%.2f, %.2f) is outside the %dx%d frame's data section ",
                         *x, *y, frame.nx, frame.ny) +
                  SectionText(frame.region));
    }
    peak_x = std::min(frame.nx - 1, static_cast<int>(std::floor(*x + 0.5)));
    peak_y = std::min(frame.ny - 1, static_cast<int>(std::floor(*y + 0.5)));
    report.spot = DescribeSource(adu, frame.valid, frame.region, peak_x, peak_y, background,
                                 pixel_sd, finder);
    report.spot.note = "given";
    report.spot_x_px = *x;
    report.spot_y_px = *y;
    report.peak_snr = kNaN;
    note_number("spot_x_px", *x, report.spot_source);
    note_number("spot_y_px", *y, from);
  } else {
    report.spot_search =
        FindSpots(adu, frame.valid, smoothed, search, background, pixel_sd, smoothed_sd, finder);
    const SpotSearch& s = report.spot_search;
    if (s.candidates.empty()) {
      return fail(Format("no spot found: nothing in the search region stands %g sd "
                         "(min_peak_snr) above the background (%.4g ADU; its 3x3 mean has sd "
                         "%.3g ADU); give --spot_x_px/--spot_y_px or --search_region",
                         options.min_peak_snr, background, smoothed_sd));
    }
    if (s.chosen < 0) {
      const SpotCandidate& c = s.candidates[0];
      return fail(Format("spot at (%.1f, %.1f) is too close to the %s for a %dx%d stamp",
                         static_cast<double>(c.peak_x), static_cast<double>(c.peak_y),
                         EdgeName(frame).c_str(), options.stamp_size, options.stamp_size));
    }
    report.spot = s.candidates[s.chosen];
    peak_x = report.spot.peak_x;
    peak_y = report.spot.peak_y;
    report.peak_snr = report.spot.significance;
    report.spot_source = "found";
    if (!s.problem.empty() && !report.spot.compact) {
      report.quality.Add("spot_not_compact", Severity::kInvalid, s.problem);
    }
  }
  if (position_given && !report.spot.compact) {
    char text[200];
    std::snprintf(text, sizeof(text),
                  "the source at the given position is not compact (size %.2f px, elongation "
                  "%.2f, core fraction %.2f)",
                  report.spot.size_px, report.spot.elongation, report.spot.core_fraction);
    report.quality.Add("spot_not_compact", Severity::kInvalid, text);
  }

  // Bias and read noise, with the pixels they may be estimated from: the bias section if
  // one is given, else the background of the data section far from the spot.
  std::optional<double> bias;
  std::string bias_from;
  if (!ResolveNumber(given, keywords, header, "bias_adu", &bias, &bias_from, &problem)) {
    return fail(problem);
  }
  std::optional<double> read_noise;
  std::string noise_from;
  if (!ResolveNumber(given, keywords, header, "read_noise_e", &read_noise, &noise_from, &problem)) {
    return fail(problem);
  }
  std::optional<NoiseSample> sample;
  if (!bias || !read_noise) {
    std::optional<std::string> section;
    std::string section_from;
    if (!ResolveText(given, keywords, header, "bias_section", &section, &section_from, &problem)) {
      return fail(problem);
    }
    if (section) {
      const std::optional<PixelRegion> region =
          ParseIrafSection(*section, frame.nx, frame.ny, &problem);
      if (!region) return fail("bias section (" + section_from + ") " + problem);
      std::vector<size_t> indices;
      for (int y = region->y_begin; y < region->y_end; ++y) {
        for (int x = region->x_begin; x < region->x_end; ++x) {
          if (frame.Valid(x, y)) indices.push_back(static_cast<size_t>(y) * frame.nx + x);
        }
      }
      // A bias section over the spot is a mistake (a wrong keyword or flag): its pixels are
      // the spot's, and no clipping makes them a bias.
      const int half = options.stamp_size / 2;
      if (region->x_begin <= peak_x + half && peak_x - half < region->x_end &&
          region->y_begin <= peak_y + half && peak_y - half < region->y_end) {
        return fail("bias section " + Printable(*section) + " (" + section_from +
                    ") overlaps the spot's stamp around (" + std::to_string(peak_x) + ", " +
                    std::to_string(peak_y) + "): it cannot measure the bias (give the "
                    "overscan's section, or --bias_adu and --read_noise_e)");
      }
      note_text("bias_section", Printable(*section), section_from);
      sample = MeasureNoise(adu, indices, "bias section " + Printable(*section));
      if (!sample) {
        return fail("bias section " + Printable(*section) + " holds " +
                    std::to_string(indices.size()) +
                    " valid pixels, too few for a bias or read noise (need " +
                    std::to_string(kMinNoisePixels) + ")");
      }
    } else {
      const std::vector<size_t> background_pixels =
          BackgroundPixels(frame, peak_x, peak_y, options.stamp_size);
      sample = MeasureNoise(adu, background_pixels, "sigma-clipped background");
      if (!sample) {
        return fail("too few background pixels (" + std::to_string(background_pixels.size()) +
                    ") to estimate the bias and read noise; give --bias_adu and "
                    "--read_noise_e, or BIASLVL and RDNOISE keywords");
      }
    }
    report.noise_rms_adu = sample->stats.stddev;
    report.noise_pixels = sample->stats.num_used;
    const std::string missing = !bias && !read_noise ? "the bias and read noise"
                                : !bias              ? "the bias"
                                                     : "the read noise";
    const std::string give = !bias && !read_noise ? "--bias_adu and --read_noise_e"
                             : !bias              ? "--bias_adu"
                                                  : "--read_noise_e";
    if (sample->at_minimum >= kClippedAtMinimum) {
      char text[256];
      std::snprintf(text, sizeof(text),
                    "%.0f %% of the %s pixels sit at exactly %g ADU, their minimum: the level is "
                    "clipped there, so ",
                    100.0 * sample->at_minimum, sample->source.c_str(), sample->minimum);
      return fail(text + missing + " cannot be estimated from them; give " + give +
                  " (or manifest columns bias_adu, read_noise_e)");
    }
    if (!read_noise && sample->stats.stddev < kMinEstimableSpreadAdu) {
      return fail(Format("the %s pixels spread by %.3g ADU, less than the ADC's step can "
                         "measure: the read noise cannot be estimated from them; give "
                         "--read_noise_e (or a manifest column read_noise_e)",
                         sample->source.c_str(), sample->stats.stddev));
    }
  } else {
    report.noise_rms_adu = kNaN;
    report.noise_pixels = 0;
  }
  if (!bias) {
    bias = sample->stats.mean;
    bias_from = sample->source;
  }
  if (!read_noise) {
    // The measured variance includes the rounding of the signal to whole ADU, a uniform
    // error of variance 1/12 ADU^2 (Sheppard's correction; exact to ~exp(-2 pi^2 s^2) for a
    // noise s >= 0.5 ADU). The read noise of the noise model excludes it.
    double variance_adu2 = sample->stats.stddev * sample->stats.stddev;
    if (sample->integer_valued && variance_adu2 - 1.0 / 12.0 > 0.0) variance_adu2 -= 1.0 / 12.0;
    read_noise = std::sqrt(variance_adu2) * *gain;
    noise_from = sample->source;
  }
  if (!std::isfinite(*bias)) return fail("bias level is not finite (" + bias_from + ")");
  if (!(std::isfinite(*read_noise) && *read_noise >= 0.0)) {
    return fail("read noise must be >= 0 and finite, got " + FormatNumber(*read_noise) + " (" +
                noise_from + ")");
  }
  note_number("bias_adu", *bias, bias_from);
  note_number("read_noise_e", *read_noise, noise_from);

  // Centroid: flux-weighted first moment of the bias-subtracted valid pixels in the 5 x 5 box
  // around the peak. Negative (noise) values are kept, so that noise does not bias it.
  if (!position_given) {
    double sum = 0.0, sum_x = 0.0, sum_y = 0.0;
    for (int y = peak_y - kCentroidHalfWidth; y <= peak_y + kCentroidHalfWidth; ++y) {
      for (int x = peak_x - kCentroidHalfWidth; x <= peak_x + kCentroidHalfWidth; ++x) {
        if (!frame.region.Contains(x, y) || !frame.Valid(x, y)) continue;
        const double w = frame.At(x, y) - *bias;
        sum += w;
        sum_x += w * x;
        sum_y += w * y;
      }
    }
    report.spot_x_px = sum > 0.0 ? sum_x / sum : peak_x;
    report.spot_y_px = sum > 0.0 ? sum_y / sum : peak_y;
    note_number("spot_x_px", report.spot_x_px, "found");
    note_number("spot_y_px", report.spot_y_px, "found");
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
  if (origin_x < frame.region.x_begin || origin_y < frame.region.y_begin ||
      origin_x + n > frame.region.x_end || origin_y + n > frame.region.y_end) {
    return fail(Format("spot at (%.2f, %.2f) is too close to the %s for a %dx%d stamp",
                       report.spot_x_px, report.spot_y_px, EdgeName(frame).c_str(), n, n));
  }
  auto in_core = [&](int x, int y) {
    return std::hypot(x - peak_x, y - peak_y) <= kCoreRadiusPx;
  };

  Stamp& stamp = exposure.stamp;
  stamp.electrons = Image(n, n);
  stamp.valid.assign(static_cast<size_t>(n) * n, 0);
  stamp.censor.assign(static_cast<size_t>(n) * n, Censor::kNone);
  const double step_e = integer_data ? *gain : 0.0;
  int bad_in_stamp = 0, bad_in_core = 0;
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const int x = origin_x + i, y = origin_y + j;
      const size_t k = static_cast<size_t>(j) * n + i;
      if (!frame.Valid(x, y)) {
        ++bad_in_stamp;
        bad_in_core += in_core(x, y);
        continue;
      }
      // A masked pixel keeps 0 e-: its value is meaningless, and 0 cannot poison a sum the
      // way NaN would.
      const double v = frame.At(x, y);
      stamp.valid[k] = 1;
      if (v >= report.ceiling_adu) {
        stamp.censor[k] = Censor::kAtOrAbove;
        stamp.electrons(i, j) = (report.ceiling_adu - *bias) * *gain;
      } else if (v <= report.floor_adu) {
        stamp.censor[k] = Censor::kAtOrBelow;
        stamp.electrons(i, j) = (report.floor_adu - *bias) * *gain;
      } else {
        stamp.electrons(i, j) = (v - *bias) * *gain;
      }
    }
  }
  if (bad_in_stamp > 0) {
    report.masks.push_back({bad_pixels != nullptr ? "bad-pixel mask or non-finite" : "non-finite",
                            bad_in_stamp, bad_in_core});
  }

  // A clipped top without a known saturation level: tied maximal pixels in the core.
  if (integer_data) {
    double top = -INFINITY;
    for (size_t k = 0; k < stamp.valid.size(); ++k) {
      if (stamp.valid[k] && stamp.censor[k] == Censor::kNone) {
        top = std::max(top, stamp.electrons.data[k]);
      }
    }
    std::vector<size_t> tied;
    for (size_t k = 0; k < stamp.valid.size(); ++k) {
      if (!stamp.valid[k] || stamp.censor[k] != Censor::kNone || stamp.electrons.data[k] != top) {
        continue;
      }
      const int x = origin_x + static_cast<int>(k % n), y = origin_y + static_cast<int>(k / n);
      if (std::hypot(x - peak_x, y - peak_y) <= 2.0) tied.push_back(k);
    }
    const double top_adu = top / *gain + *bias;
    if (tied.size() >= 2 && top_adu - background >= kFlatTopSignificance * pixel_sd &&
        top_adu < report.ceiling_adu) {
      for (size_t k : tied) stamp.censor[k] = Censor::kAtOrAbove;
      char text[200];
      std::snprintf(text, sizeof(text),
                    "a flat top: %zu pixels at exactly %g ADU, the stamp's maximum, with no "
                    "saturation level known: clipped there, fitted as at-or-above",
                    tied.size(), std::round(top_adu * 1e6) / 1e6);
      report.quality.Add("clipped_top", Severity::kSuspect, text);
      report.ceiling_source += "; flat top detected at " + FormatNumber(top_adu) + " ADU";
    }
  }

  // Columns that differ from their neighbours, crossing the stamp.
  if (options.mask_column_defects) {
    const double column_sd = std::max(report.background_sd_adu, std::sqrt(1.0 / 12.0));
    std::vector<ColumnDefect> defects =
        FindColumnDefects(adu, frame.valid, frame.region, origin_x, origin_x + n - 1, peak_y, c + 2,
                          column_sd, kColumnSignificance, &report.columns_checked);
    if (!report.columns_checked) {
      // A frame little taller than the stamp has no rows clear of it: judge the columns on the
      // rows more than kColumnRowsFromSpot from the spot. A column of the spot's own light is
      // no defect there: its neighbours carry the same light (the test is against them).
      defects = FindColumnDefects(adu, frame.valid, frame.region, origin_x, origin_x + n - 1,
                                  peak_y, kColumnRowsFromSpot, column_sd, kColumnSignificance,
                                  &report.columns_checked);
    }
    for (const ColumnDefect& d : defects) {
      StampMask mask;
      char text[160];
      std::snprintf(text, sizeof(text), "column %d (%s, %+.4g ADU against its neighbours, %.0f sd)",
                    d.x, d.excess_adu > 0 ? "hot" : "dark", d.excess_adu, d.significance);
      mask.reason = text;
      for (int j = 0; j < n; ++j) {
        const size_t k = static_cast<size_t>(j) * n + (d.x - origin_x);
        if (!stamp.valid[k]) continue;
        stamp.valid[k] = 0;
        ++mask.pixels;
        mask.core_pixels += in_core(d.x, origin_y + j);
      }
      report.column_defects.push_back(d);
      if (mask.pixels == 0) continue;
      report.quality.Add("column_defect", mask.core_pixels > 0 ? Severity::kSuspect : Severity::kNote,
                         "masked " + mask.reason + ": " + std::to_string(mask.pixels) +
                             " stamp pixels" +
                             (mask.core_pixels > 0 ? ", " + std::to_string(mask.core_pixels) +
                                                         " of them in the spot's core"
                                                   : ""));
      report.masks.push_back(mask);
    }
  }

  // Other sources in the stamp: masked beyond the spot's core.
  if (options.mask_stamp_sources) {
    std::vector<uint8_t> frame_valid_no_censor = frame.valid;
    const double noise_adu = std::sqrt((*read_noise / *gain) * (*read_noise / *gain) +
                                       (integer_data ? 1.0 / 12.0 : 0.0));
    std::vector<uint8_t> before = stamp.valid;
    report.stamp_sources = FindAndMaskStampSources(
        adu, frame_valid_no_censor, origin_x, origin_y, n, peak_x, peak_y, *bias,
        std::max(noise_adu, 1e-12), 0.0, kSourceSignificance, kSourceMinDistancePx,
        kSourceProtectPx, &stamp.valid);
    for (const StampSource& s : report.stamp_sources) {
      char text[220];
      std::snprintf(text, sizeof(text),
                    "another source at (%d, %d), %.1f px from the spot (%.4g ADU above the "
                    "background): %d pixels masked",
                    s.x, s.y, s.distance_px, s.peak_adu, s.masked_pixels);
      // A source this near may have light inside the protected core.
      const bool near = s.distance_px < kSourceProtectPx + 1.5;
      report.quality.Add("another_source", near ? Severity::kSuspect : Severity::kNote,
                         std::string(text) +
                             (near ? "; it is close enough for its light to reach the core"
                                   : ""));
      if (s.masked_pixels > 0) {
        report.masks.push_back({std::string("source at (") + std::to_string(s.x) + ", " +
                                    std::to_string(s.y) + ")",
                                s.masked_pixels, 0});
      }
    }
  }

  // Censoring and the core.
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const size_t k = static_cast<size_t>(j) * n + i;
      if (!stamp.valid[k]) continue;
      if (stamp.censor[k] == Censor::kAtOrAbove) ++report.censored_high;
      if (stamp.censor[k] == Censor::kAtOrBelow) ++report.censored_low;
      if (stamp.censor[k] != Censor::kNone && in_core(origin_x + i, origin_y + j)) {
        ++report.censored_core;
      }
    }
  }
  if (report.censored_high > 0) {
    const int core_high = [&] {
      int count = 0;
      for (int j = 0; j < n; ++j) {
        for (int i = 0; i < n; ++i) {
          const size_t k = static_cast<size_t>(j) * n + i;
          count += stamp.valid[k] && stamp.censor[k] == Censor::kAtOrAbove &&
                   in_core(origin_x + i, origin_y + j);
        }
      }
      return count;
    }();
    if (core_high > 0 && !report.quality.Has("clipped_top")) {
      report.quality.Add("saturated_core", Severity::kSuspect,
                         std::to_string(core_high) + " core pixel(s) at or above " +
                             FormatNumber(report.ceiling_adu) + " ADU (" + report.ceiling_source +
                             "): fitted as censored, the width rests on the wings");
    } else if (core_high == 0) {
      report.quality.Add("saturated_pixels", Severity::kNote,
                         std::to_string(report.censored_high) +
                             " stamp pixel(s) at or above " + FormatNumber(report.ceiling_adu) +
                             " ADU: fitted as censored");
    }
  }
  // A peak near the ADC's full scale with no saturation level known may be compressed.
  if (!saturation && std::isfinite(image.adc_max) && report.censored_high == 0 &&
      std::isfinite(report.peak_adu) && image.adc_max > 0 &&
      report.peak_adu >= kNearFullScale * image.adc_max) {
    report.quality.Add(
        "near_full_scale", Severity::kSuspect,
        "the peak (" + FormatNumber(report.peak_adu) + " ADU) is within " +
            FormatNumber(100 * (1 - kNearFullScale)) + " % of the ADC's full scale (" +
            FormatNumber(image.adc_max) +
            " ADU) and no saturation level is known: it may be compressed or saturated "
            "(give --saturation_adu, or fit a series of exposure times)");
  }
  // Masked pixels of the core.
  {
    int masked_core = 0;
    for (int j = 0; j < n; ++j) {
      for (int i = 0; i < n; ++i) {
        masked_core += !stamp.valid[static_cast<size_t>(j) * n + i] &&
                       in_core(origin_x + i, origin_y + j);
      }
    }
    if (!stamp.valid[static_cast<size_t>(c) * n + c]) {
      report.quality.Add("peak_masked", Severity::kInvalid,
                         "the spot's peak pixel is masked (non-finite or flagged bad): the fit "
                         "cannot see the core");
    } else if (masked_core > 0) {
      report.quality.Add("masked_core", Severity::kSuspect,
                         std::to_string(masked_core) + " pixel(s) of the spot's core are masked");
    }
  }
  report.masked_pixels = n * n - stamp.NumValid();
  if (report.masked_pixels == n * n) {
    return fail("every pixel of the " + std::to_string(n) + "x" + std::to_string(n) +
                " stamp at (" + std::to_string(origin_x) + ", " + std::to_string(origin_y) +
                ") is masked (non-finite or flagged)");
  }
  stamp.origin_x = origin_x;
  stamp.origin_y = origin_y;
  stamp.gain_e_per_adu = *gain;
  stamp.read_noise_e = *read_noise;
  stamp.bias_adu = *bias;
  stamp.saturation_adu = report.ceiling_adu;
  stamp.adc_step_e = step_e;

  // Metadata for the fit and the trends.
  ExposureInfo& info = stamp.info;
  info.source = source;
  struct Physical {
    const char* quantity;
    double* field;
    bool positive;  // else >= 0 or any finite value
    bool any;
  };
  const Physical physical[] = {{"wavelength_nm", &info.wavelength_nm, true, false},
                               {"exptime_s", &info.exptime_s, false, false},
                               {"pixel_um", &info.pixel_um, true, false},
                               {"focus_position_um", &info.focus_position_um, false, true}};
  for (const Physical& p : physical) {
    std::optional<double> value;
    if (!ResolveNumber(given, keywords, header, p.quantity, &value, &from, &problem)) {
      return fail(problem);
    }
    *p.field = kNaN;
    if (!value) {
      note_number(p.quantity, kNaN, "unknown");
      continue;
    }
    if (!p.any && !(p.positive ? *value > 0.0 : *value >= 0.0)) {
      return fail(std::string(p.quantity) + " must be " + (p.positive ? "positive" : ">= 0") +
                  ", got " + FormatNumber(*value) + " (" + from + ")");
    }
    *p.field = *value;
    note_number(p.quantity, *value, from);
  }
  return exposure;
}

std::optional<Exposure> LoadExposure(const std::string& path, const CalibrationOptions& options,
                                     std::string* error) {
  std::string problem;
  if (!options.IsValid(&problem)) {
    *error = "'" + path + "': " + problem;
    return std::nullopt;
  }
  // The user's bad-pixel mask, opened once (read per segment when it has several images).
  std::unique_ptr<FitsImageFile> mask_file;
  std::optional<FitsImage> mask;
  auto load_mask = [&](const std::string& hdu) -> bool {
    const GivenValue* m = options.given.Find("bad_pixel_mask");
    if (m == nullptr || !m->text) return true;
    std::string why;
    if (!mask_file) mask_file = FitsImageFile::Open(*m->text, &why);
    if (!mask_file || mask_file->images().empty()) {
      *error = "'" + path + "': bad-pixel mask: " + (why.empty() ? "'" + *m->text + "' holds no image" : why);
      return false;
    }
    // A mask with one image serves every segment; one with several is read per segment.
    mask = mask_file->Read(mask_file->images().size() > 1 ? hdu : "", &why);
    if (!mask) {
      *error = "'" + path + "': bad-pixel mask: " + why;
      return false;
    }
    return true;
  };
  // The file is opened (and screened) once, whatever number of segments it holds.
  const std::unique_ptr<FitsImageFile> file = FitsImageFile::Open(path, error);
  if (!file) return std::nullopt;
  const GivenValue* hdu = options.given.Find("hdu");
  if (hdu != nullptr && hdu->text) {
    std::optional<FitsImage> image = file->Read(*hdu->text, error);
    if (!image) return std::nullopt;
    if (!load_mask(*hdu->text)) return std::nullopt;
    return CalibrateExposure(*image, path, options, error, mask ? &mask->pixels : nullptr);
  }
  const std::vector<FitsHduInfo>& images = file->images();
  if (images.size() <= 1) {
    std::optional<FitsImage> image = file->Read("", error);
    if (!image) return std::nullopt;
    if (!load_mask("")) return std::nullopt;
    return CalibrateExposure(*image, path, options, error, mask ? &mask->pixels : nullptr);
  }
  // A multi-extension file (one image per amplifier segment): the segment holding the most
  // significant compact source.
  std::optional<Exposure> best;
  std::string best_name, tried;
  for (const FitsHduInfo& info : images) {
    const std::string selector = info.extname.empty() ? std::to_string(info.index) : info.extname;
    std::string reason;
    std::optional<FitsImage> image = file->Read(selector, &reason);
    std::optional<Exposure> e;
    if (image) {
      if (!load_mask(selector)) return std::nullopt;
      e = CalibrateExposure(*image, path, options, &reason, mask ? &mask->pixels : nullptr);
    }
    if (!e) {
      const size_t colon = reason.find("': ");
      tried += (tried.empty() ? "" : "; ") + selector + ": " +
               (colon == std::string::npos ? reason : reason.substr(colon + 3));
      continue;
    }
    tried += (tried.empty() ? "" : "; ") + selector + ": " +
             (e->report.spot.compact ? "compact source" : "no compact source") +
             Format(" at significance %.3g", e->report.peak_snr);
    // Compact sources first, then the most significant.
    const bool better =
        !best || (e->report.spot.compact && !best->report.spot.compact) ||
        (e->report.spot.compact == best->report.spot.compact &&
         e->report.peak_snr > best->report.peak_snr);
    if (better) {
      best = std::move(e);
      best_name = selector;
    }
  }
  if (!best) {
    *error = "'" + path + "': no segment holds a usable spot (" + tried + ")";
    return std::nullopt;
  }
  best->report.metadata["hdu"].source =
      "auto: the segment holding the most significant compact source (" + tried + ")";
  return best;
}

nlohmann::json CalibrationReportJson(const CalibrationReport& r) {
  using nlohmann::json;
  auto num = [](double v) { return std::isfinite(v) ? json(v) : json(nullptr); };
  json candidates = json::array();
  for (const SpotCandidate& c : r.spot_search.candidates) candidates.push_back(SpotCandidateJson(c));
  json masks = json::array();
  for (const StampMask& m : r.masks) {
    masks.push_back({{"reason", m.reason}, {"pixels", m.pixels}, {"core_pixels", m.core_pixels}});
  }
  json sources = json::array();
  for (const StampSource& s : r.stamp_sources) {
    sources.push_back({{"peak_px", {s.x, s.y}},
                       {"distance_px", s.distance_px},
                       {"peak_adu_above_background", s.peak_adu},
                       {"masked_radius_px", s.radius_px},
                       {"masked_pixels", s.masked_pixels}});
  }
  json columns = json::array();
  for (const ColumnDefect& d : r.column_defects) {
    columns.push_back({{"x", d.x}, {"excess_adu", d.excess_adu}, {"significance", d.significance}});
  }
  return {{"metadata", MetadataRecordJson(r.metadata)},
          {"spot",
           {{"source", r.spot_source},
            {"x_px", num(r.spot_x_px)},
            {"y_px", num(r.spot_y_px)},
            {"peak_px", {r.peak_x_px, r.peak_y_px}},
            {"peak_adu", num(r.peak_adu)},
            {"peak_e", num(r.peak_e)},
            {"significance", num(r.peak_snr)},
            {"shape", SpotCandidateJson(r.spot)},
            {"candidates", candidates}}},
          {"background_adu", num(r.background_adu)},
          {"background_sd_adu", num(r.background_sd_adu)},
          {"noise_rms_adu", num(r.noise_rms_adu)},
          {"noise_pixels", r.noise_pixels},
          {"censoring",
           {{"ceiling_adu", num(r.ceiling_adu)},
            {"ceiling_source", r.ceiling_source},
            {"floor_adu", num(r.floor_adu)},
            {"floor_source", r.floor_source},
            {"censored_high", r.censored_high},
            {"censored_low", r.censored_low},
            {"censored_core", r.censored_core}}},
          {"masked_pixels", r.masked_pixels},
          {"masks", masks},
          {"columns_checked", r.columns_checked},
          {"column_defects", columns},
          {"other_sources", sources},
          {"quality", r.quality.ToJson()}};
}

}  // namespace ccdpsf
