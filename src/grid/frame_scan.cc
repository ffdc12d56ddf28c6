// One pass over a frame's rows: every source, and cutouts of those that can be fitted
// (frame_scan.h).
#include "ccdpsf/grid/frame_scan.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>

#include "ccdpsf/metadata.h"
#include "internal/fnv1a.h"
#include "internal/text.h"

namespace ccdpsf::grid {
namespace {

// Shape-measure reach (spot_finder.h): the surround extends 7 px from the peak, the local
// maximum test 2 px, the smoothing 1 px.
constexpr int kShapeReach = 7;
// The centroid's box half-width [px] (5 x 5, as calibration's).
constexpr int kCentroidHalf = 2;
// Every kSampleStride-th pixel of a strip measures its background: ~4 000 pixels of a
// 4096-wide, 128-row strip, enough for a level and sd to ~2 %.
constexpr size_t kSampleStride = 131;

// A section of the frame: given or keyword (through the map), parsed; the whole frame when
// neither gives one.
bool ResolveSection(const CalibrationOptions& calibration, const FitsHeader& header,
                    const std::string& quantity, int nx, int ny, const std::string& path,
                    std::optional<PixelRegion>* region, std::string* error) {
  std::optional<std::string> text;
  std::string source, problem;
  if (!ResolveText(calibration.given, calibration.keywords, header, quantity, &text, &source,
                   &problem)) {
    *error = "'" + path + "': " + problem;
    return false;
  }
  region->reset();
  if (!text) return true;
  *region = ParseIrafSection(*text, nx, ny, &problem);
  if (!*region) {
    *error = "'" + path + "': " + quantity + " (" + source + ") " + problem;
    return false;
  }
  return true;
}

std::string Format(const char* format, double a, double b, double c) {
  char text[200];
  std::snprintf(text, sizeof(text), format, a, b, c);
  return text;
}

}  // namespace

bool ScanFrame(const std::string& path, const CalibrationOptions& calibration,
               const FrameScanOptions& options, ScannedFrame* out, std::string* error) {
  std::string hdu;
  if (const GivenValue* v = calibration.given.Find("hdu"); v != nullptr && v->text) hdu = *v->text;
  std::unique_ptr<FitsImageStream> stream = FitsImageStream::Open(path, hdu, error);
  if (!stream) return false;
  const int nx = stream->nx(), ny = stream->ny();
  const FitsImage& meta = stream->image();
  *out = ScannedFrame();
  out->path = path;
  out->hdu = hdu;
  out->hdu_number = meta.hdu;
  out->extname = meta.extname;
  out->nx = nx;
  out->ny = ny;
  out->header = meta.header;

  std::optional<PixelRegion> data, search;
  if (!ResolveSection(calibration, meta.header, "data_section", nx, ny, path, &data, error) ||
      !ResolveSection(calibration, meta.header, "search_region", nx, ny, path, &search, error)) {
    return false;
  }
  out->data_region = data ? *data : PixelRegion{0, nx, 0, ny};
  PixelRegion look = out->data_region;  // where peaks may be
  if (search) {
    look.x_begin = std::max(look.x_begin, search->x_begin);
    look.x_end = std::min(look.x_end, search->x_end);
    look.y_begin = std::max(look.y_begin, search->y_begin);
    look.y_end = std::min(look.y_end, search->y_end);
    if (look.x_begin >= look.x_end || look.y_begin >= look.y_end) {
      *error = "'" + path + "': the search region lies outside the data section";
      return false;
    }
  }
  const bool integer_data = meta.bitpix > 0;
  // Section keywords describe the whole frame; a cutout is given its own data section.
  FitsHeader cutout_header;
  for (const FitsKey& key : meta.header) {
    bool section = false;
    for (const char* q : {"data_section", "bias_section"}) {
      const KeywordRule* rule = calibration.keywords.Find(q);
      if (rule != nullptr && !rule->keyword.empty() &&
          internal::ToUpper(key.name) == rule->keyword) {
        section = true;
      }
    }
    if (!section) cutout_header.push_back(key);
  }

  SpotFinderOptions finder = options.finder;
  finder.max_candidates = std::numeric_limits<int>::max();
  const int stamp_half = (finder.stamp_size - 1) / 2;
  const int margin = std::max(options.cutout_half, stamp_half + kShapeReach) + 2;
  const int strip = std::max(16, options.strip_rows);

  // The window holds rows [w0, w1) of the frame; the rows of the strip in hand are
  // [core_begin, core_end), with up to `margin` rows on either side.
  internal::Fnv1a digest;  // of the rows in the order read (each once)
  Image window(nx, 0);
  window.data.reserve(static_cast<size_t>(nx) * (strip + 2 * margin));
  int w0 = 0, w1 = 0;
  for (int core_begin = 0; core_begin < ny;) {
    const int core_end = std::min(ny, core_begin + strip);
    const int need = std::min(ny, core_end + margin);
    if (need > w1) {
      window.data.resize(static_cast<size_t>(nx) * (need - w0));
      double* rows = window.data.data() + static_cast<size_t>(nx) * (w1 - w0);
      if (!stream->ReadRows(w1, need - w1, rows, error)) return false;
      digest.Add(rows, static_cast<size_t>(nx) * (need - w1) * sizeof(double));
      w1 = need;
      window.ny = w1 - w0;
    }
    // Detection in window coordinates: frame row y is window row y - w0.
    std::vector<uint8_t> valid(window.data.size());
    for (size_t k = 0; k < valid.size(); ++k) valid[k] = std::isfinite(window.data[k]) ? 1 : 0;
    PixelRegion region{out->data_region.x_begin, out->data_region.x_end,
                       std::max(out->data_region.y_begin, w0) - w0,
                       std::min(out->data_region.y_end, w1) - w0};
    if (region.y_begin < region.y_end && look.y_begin < core_end && core_begin < look.y_end) {
      const Image smoothed = SmoothBox3(window, valid, region);
      std::vector<double> raw_sample, smooth_sample;
      for (int y = region.y_begin; y < region.y_end; ++y) {
        for (int x = region.x_begin; x < region.x_end; ++x) {
          const size_t k = static_cast<size_t>(y) * nx + x;
          if (k % kSampleStride != 0) continue;
          if (valid[k]) raw_sample.push_back(window.data[k]);
          if (std::isfinite(smoothed.data[k])) smooth_sample.push_back(smoothed.data[k]);
        }
      }
      const std::optional<ClippedStats> raw = SigmaClippedStats(std::move(raw_sample));
      const std::optional<ClippedStats> smooth = SigmaClippedStats(std::move(smooth_sample));
      if (raw) {
        const double rounding = integer_data ? std::sqrt(1.0 / 12.0) : 0.0;
        const double background = raw->median;
        const double pixel_sd = std::max(raw->stddev, rounding);
        const double smoothed_sd = std::max(smooth ? smooth->stddev : 0.0, rounding / 3.0);
        PixelRegion peaks = region;  // peaks in this strip's rows and the search region
        peaks.x_begin = look.x_begin;
        peaks.x_end = look.x_end;
        peaks.y_begin = std::max({region.y_begin, core_begin - w0, look.y_begin - w0});
        peaks.y_end = std::min({region.y_end, core_end - w0, look.y_end - w0});
        const SpotSearch found =
            FindSpots(window, valid, smoothed, region, background, pixel_sd, smoothed_sd, finder);
        for (const SpotCandidate& c : found.candidates) {
          if (!peaks.Contains(c.peak_x, c.peak_y)) continue;
          FrameSource s;
          s.shape = c;
          s.shape.note.clear();
          s.shape.peak_y += w0;
          s.background_adu = background;
          double sum = 0.0, sx = 0.0, sy = 0.0, core = 0.0;
          for (int dy = -kCentroidHalf; dy <= kCentroidHalf; ++dy) {
            for (int dx = -kCentroidHalf; dx <= kCentroidHalf; ++dx) {
              const int x = c.peak_x + dx, y = c.peak_y + dy;
              if (!region.Contains(x, y) || !valid[static_cast<size_t>(y) * nx + x]) continue;
              const double w = window(x, y) - background;
              sum += w;
              sx += w * x;
              sy += w * y;
              if (std::abs(dx) <= 1 && std::abs(dy) <= 1) core += w;
            }
          }
          s.x_px = sum > 0.0 ? sx / sum : c.peak_x;
          s.y_px = (sum > 0.0 ? sy / sum : c.peak_y) + w0;
          s.single_pixel_fraction = core > 0.0 ? (c.peak_adu - background) / core : 1.0;
          if (!c.stamp_fits) {
            s.refused = "edge";
            s.reason = "its " + std::to_string(finder.stamp_size) + " x " +
                       std::to_string(finder.stamp_size) +
                       " stamp does not fit inside the data section";
          } else if (s.single_pixel_fraction > options.max_single_pixel_fraction) {
            s.refused = "single_pixel";
            s.reason = Format(
                "%.0f %% of its 3 x 3 core signal is in its peak "
                "pixel (a hot pixel or a cosmic-ray hit; a spot holds < %.0f %%)",
                100.0 * s.single_pixel_fraction, 100.0 * options.max_single_pixel_fraction, 0);
          } else if (!c.compact) {
            s.refused = "extended";
            s.reason = Format("size %.2f px, elongation %.2f, core fraction %.2f", c.size_px,
                              c.elongation, c.core_fraction);
          } else if (!c.isolated) {
            s.refused = "crowded";
            s.reason = Format(
                "other light 4-7 px from its peak (%.0f %% of its core "
                "signal; at most %.0f %% allowed)",
                100.0 * c.surround_fraction, 100.0 * finder.max_surround, 0);
          }
          if (s.refused.empty()) {
            FrameCutout cut;
            cut.x0 = std::max(0, c.peak_x - options.cutout_half);
            cut.y0 = std::max(0, s.shape.peak_y - options.cutout_half);
            const int x1 = std::min(nx, c.peak_x + options.cutout_half + 1);
            const int y1 = std::min(ny, s.shape.peak_y + options.cutout_half + 1);
            cut.image.header = cutout_header;
            cut.image.bitpix = meta.bitpix;
            cut.image.hdu = meta.hdu;
            cut.image.extname = meta.extname;
            cut.image.adc_min = meta.adc_min;
            cut.image.adc_max = meta.adc_max;
            cut.image.pixels = Image(x1 - cut.x0, y1 - cut.y0);
            for (int y = cut.y0; y < y1; ++y) {
              std::memcpy(&cut.image.pixels(0, y - cut.y0), &window(cut.x0, y - w0),
                          sizeof(double) * (x1 - cut.x0));
            }
            s.cutout = static_cast<int>(out->cutouts.size());
            out->cutouts.push_back(std::move(cut));
          }
          out->sources.push_back(std::move(s));
        }
      }
    }
    // Keep the margin below the next strip; the rest of the window goes.
    const int keep_from = std::max(w0, core_end - margin);
    if (keep_from > w0) {
      const size_t drop = static_cast<size_t>(nx) * (keep_from - w0);
      window.data.erase(window.data.begin(), window.data.begin() + static_cast<long>(drop));
      w0 = keep_from;
      window.ny = w1 - w0;
    }
    core_begin = core_end;
  }
  std::stable_sort(out->sources.begin(), out->sources.end(),
                   [](const FrameSource& a, const FrameSource& b) {
                     return a.shape.peak_y != b.shape.peak_y ? a.shape.peak_y < b.shape.peak_y
                                                             : a.shape.peak_x < b.shape.peak_x;
                   });
  out->pixel_digest = digest.value();
  return true;
}

}  // namespace ccdpsf::grid
