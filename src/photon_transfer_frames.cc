// The frames of a photon-transfer set (photon_transfer_frames.h): exposure times, regions,
// ADC limits, pairs under one illumination and the bias level.
#include "ccdpsf/photon_transfer_frames.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>
#include <set>

#include "ccdpsf/exposure.h"
#include "internal/json_number.h"

namespace ccdpsf {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

// A black level clipped by the ADC: at least this fraction of a frame's pixels (and at least
// kMinFloorPixels) at exactly its minimum value. The same rule as exposure.h's calibration:
// unclipped noise of sd >= 0.5 ADU puts well under 1 % of a large frame at its single
// lowest value.
constexpr double kFloorFraction = 0.01;
constexpr long long kMinFloorPixels = 10;
// Exposure times equal within this relative tolerance are the same.
constexpr double kExptimeTolerance = 1e-6;

std::string Num(double value) {
  char text[64];
  std::snprintf(text, sizeof(text), "%.4g", value);
  return text;
}

bool SameExptime(double a, double b) {
  return std::fabs(a - b) <=
         kExptimeTolerance * std::max(1.0, std::max(std::fabs(a), std::fabs(b)));
}

// The data region: DATASEC when the header has a valid one, else the whole frame.
PixelRegion DataRegion(const FitsImage& image, const std::string& name,
                       std::vector<std::string>* warnings) {
  PixelRegion whole{0, image.pixels.nx, 0, image.pixels.ny};
  std::optional<std::string> section = FindString(image.header, "DATASEC");
  if (!section) return whole;
  std::string error;
  std::optional<PixelRegion> region =
      ParseIrafSection(*section, image.pixels.nx, image.pixels.ny, &error);
  if (!region) {
    warnings->push_back(name + ": DATASEC ignored (" + error + ")");
    return whole;
  }
  return *region;
}

// Floor, ceiling and the frame's record of them.
TransferFrame PrepareFrame(const FitsImage& image, const std::string& name,
                           const TransferFrameOptions& options, PtcFrameInfo* info,
                           std::vector<std::string>* warnings) {
  TransferFrame p;
  p.image = &image;
  p.region = DataRegion(image, name, warnings);
  const Image& px = image.pixels;
  double minimum = kInf;
  long long at_minimum = 0, finite = 0;
  for (int y = p.region.y_begin; y < p.region.y_end; ++y) {
    for (int x = p.region.x_begin; x < p.region.x_end; ++x) {
      const double v = px(x, y);
      if (!std::isfinite(v)) continue;
      ++finite;
      if (v < minimum) {
        minimum = v;
        at_minimum = 1;
      } else if (v == minimum) {
        ++at_minimum;
      }
    }
  }
  info->floor_pixel_fraction = finite > 0 ? static_cast<double>(at_minimum) / finite : 0.0;
  info->floor_clipped =
      finite > 0 && at_minimum >= kMinFloorPixels && info->floor_pixel_fraction >= kFloorFraction;
  // Pixels at the ADC's bottom are at the floor even when there are few of them.
  p.floor = info->floor_clipped ? minimum : image.adc_min;
  info->floor_adu = p.floor;

  p.ceiling = image.adc_max;
  info->ceiling_source = std::isfinite(image.adc_max) ? "ADC maximum" : "none";
  double saturation = options.saturation_adu;
  std::string saturation_source = "option";
  if (!std::isfinite(saturation)) {
    if (std::optional<double> s = FindNumber(image.header, "SATURATE")) {
      saturation = *s;
      saturation_source = "keyword SATURATE";
    }
  }
  if (std::isfinite(saturation) && saturation < p.ceiling) {
    p.ceiling = saturation;
    info->ceiling_source = saturation_source;
  }
  info->ceiling_adu = p.ceiling;
  return p;
}

}  // namespace

bool TransferFrameOptions::IsValid(std::string* error) const {
  if (!std::isnan(bias_adu) && !std::isfinite(bias_adu)) {
    *error = "the bias level must be finite";
    return false;
  }
  if (!std::isnan(saturation_adu) && !std::isfinite(saturation_adu)) {
    *error = "the saturation level must be finite";
    return false;
  }
  for (double t : exptime_s) {
    if (!std::isnan(t) && !(std::isfinite(t) && t >= 0.0)) {
      *error = "an exposure time must be >= 0 s (got " + Num(t) + ")";
      return false;
    }
  }
  if (!scene.empty() && !exptime_s.empty() && scene.size() != exptime_s.size()) {
    *error = "scene must be parallel to exptime_s";
    return false;
  }
  if (!exptime_sources.empty() && exptime_sources.size() != exptime_s.size()) {
    *error = "exptime_sources must be parallel to exptime_s";
    return false;
  }
  return true;
}

bool PrepareTransferFrames(const std::vector<FitsImage>& frames,
                           const std::vector<std::string>& names_in,
                           const TransferFrameOptions& options, TransferFrameSet* set,
                           std::vector<std::string>* warnings, std::string* error) {
  *set = TransferFrameSet{};
  if (!options.scene.empty() && options.scene.size() != frames.size()) {
    *error = "got " + std::to_string(options.scene.size()) + " scenes for " +
             std::to_string(frames.size()) + " frames";
    return false;
  }
  if (!options.exptime_s.empty() && options.exptime_s.size() != frames.size()) {
    *error = "got " + std::to_string(options.exptime_s.size()) + " exposure times for " +
             std::to_string(frames.size()) + " frames";
    return false;
  }
  set->names = names_in;
  set->names.resize(frames.size());
  for (size_t i = 0; i < frames.size(); ++i) {
    if (set->names[i].empty()) set->names[i] = "frame " + std::to_string(i + 1);
  }
  set->frames.resize(frames.size());
  set->exptimes.assign(frames.size(), kNaN);
  set->info.resize(frames.size());
  for (size_t i = 0; i < frames.size(); ++i) {
    PtcFrameInfo& info = set->info[i];
    info.name = set->names[i];
    if (frames[i].pixels.empty()) {
      *error = set->names[i] + ": empty image";
      return false;
    }
    if (!options.exptime_s.empty() && std::isfinite(options.exptime_s[i])) {
      set->exptimes[i] = options.exptime_s[i];
      info.exptime_source = options.exptime_sources.empty() ? "option" : options.exptime_sources[i];
    } else if (std::optional<double> t = FindNumber(frames[i].header, "EXPTIME")) {
      if (std::isfinite(*t) && *t >= 0.0) {
        set->exptimes[i] = *t;
        info.exptime_source = "keyword EXPTIME";
      }
    }
    info.exptime_s = set->exptimes[i];
    set->frames[i] = PrepareFrame(frames[i], set->names[i], options, &info, warnings);
    // The ADC's step in physical units: the range over the 2^BITPIX - 1 steps (BSCALE), 1
    // when the range is not finite (64-bit integers). Floating-point data are not rounded.
    if (frames[i].bitpix > 0) {
      const double range = frames[i].adc_max - frames[i].adc_min;
      const double step = std::isfinite(range) && frames[i].bitpix < 64
                              ? range / (std::ldexp(1.0, frames[i].bitpix) - 1.0)
                              : 1.0;
      set->rounding_adu2 = std::max(set->rounding_adu2, step * step / 12.0);
    }
  }
  return true;
}

std::vector<std::pair<size_t, size_t>> FindIlluminationPairs(const TransferFrameSet& set,
                                                             const TransferFrameOptions& options,
                                                             std::vector<std::string>* warnings) {
  std::vector<std::pair<size_t, size_t>> pairs;
  const size_t n = set.frames.size();
  const std::vector<double>& exptimes = set.exptimes;
  const std::vector<std::string>& names = set.names;
  std::set<std::string> not_paired;  // why frames sharing an exposure time were not paired
  std::vector<bool> taken(n, false);
  for (size_t i = 0; i < n; ++i) {
    if (taken[i] || !std::isfinite(exptimes[i])) continue;
    const FitsImage& fi = *set.frames[i].image;
    for (size_t j = i + 1; j < n; ++j) {
      if (taken[j] || !std::isfinite(exptimes[j]) || !SameExptime(exptimes[i], exptimes[j])) {
        continue;
      }
      if (!options.scene.empty() && options.scene[i] != options.scene[j]) continue;
      const FitsImage& fj = *set.frames[j].image;
      std::string differs;
      for (const char* key : {"WAVELEN", "FOCUSPOS"}) {
        const std::optional<double> a = FindNumber(fi.header, key);
        const std::optional<double> b = FindNumber(fj.header, key);
        if (a && b && *a != *b) differs = key;
      }
      if (!differs.empty()) {
        not_paired.insert(names[i] + " and " + names[j] + " share an exposure time but not " +
                          differs + ": not paired");
        continue;
      }
      if (fj.pixels.nx != fi.pixels.nx || fj.pixels.ny != fi.pixels.ny) {
        not_paired.insert(names[i] + " and " + names[j] +
                          " share an exposure time but not a size: not paired");
        continue;
      }
      pairs.emplace_back(i, j);
      taken[i] = taken[j] = true;
      break;
    }
  }
  // Said only when some frame is left without a partner, and once (a listing of every
  // combination that does not pair would bury the other warnings).
  size_t unpaired_with_reason = 0;
  for (size_t i = 0; i < n; ++i) unpaired_with_reason += !taken[i];
  if (unpaired_with_reason > 0 && !not_paired.empty()) {
    warnings->push_back(*not_paired.begin() +
                        (not_paired.size() > 1
                             ? " (and " + std::to_string(not_paired.size() - 1) + " more)"
                             : std::string()));
  }
  return pairs;
}

int DescribePairs(const std::vector<std::pair<size_t, size_t>>& pairs, TransferFrameSet* set,
                  std::vector<std::string>* warnings) {
  const std::vector<std::string>& names = set->names;
  std::vector<bool> in_pair(set->frames.size(), false);
  for (size_t p = 0; p < pairs.size(); ++p) {
    const auto [i, j] = pairs[p];
    in_pair[i] = in_pair[j] = true;
    set->info[i].role = "pair " + std::to_string(p + 1) + " (with " + names[j] + ")";
    set->info[j].role = "pair " + std::to_string(p + 1) + " (with " + names[i] + ")";
  }
  int unpaired = 0;
  for (size_t i = 0; i < set->frames.size(); ++i) {
    if (in_pair[i]) continue;
    ++unpaired;
    set->info[i].role = std::isfinite(set->exptimes[i])
                            ? "not used: no partner under the same illumination"
                            : "not used: exposure time unknown";
  }
  if (unpaired > 0) {
    warnings->push_back(std::to_string(unpaired) +
                        " frame(s) without a partner under the "
                        "same illumination not used");
  }
  return static_cast<int>(2 * pairs.size());
}

BiasEstimate ResolveTransferBias(const TransferFrameSet& set, const TransferFrameOptions& options,
                                 std::vector<std::string>* warnings) {
  BiasEstimate bias;
  if (std::isfinite(options.bias_adu)) {
    bias.value = options.bias_adu;
    bias.sd = 0.0;
    bias.source = options.bias_source;
    return bias;
  }
  const size_t n = set.frames.size();
  {
    double sum = 0.0;
    bool all = true;
    for (const TransferFrame& f : set.frames) {
      std::optional<double> v = FindNumber(f.image->header, "BIASLVL");
      if (!v || !std::isfinite(*v)) {
        all = false;
        break;
      }
      sum += *v;
    }
    if (all && n > 0) {
      bias.value = sum / n;
      bias.sd = 0.0;
      bias.source = "keyword BIASLVL";
      return bias;
    }
  }
  // A sample of pixels: its clipped mean and the mean's sd, unless the sample sits on the
  // floor (then the mean is biased high and is refused).
  struct Pooled {
    double sum = 0.0, var_sum = 0.0;
    int count = 0;
    bool clipped = false;
  };
  auto add_region = [&](Pooled* pool, size_t i, const PixelRegion& r) {
    std::vector<double> values;
    long long at_floor = 0;
    const Image& px = set.frames[i].image->pixels;
    for (int y = r.y_begin; y < r.y_end; ++y) {
      for (int x = r.x_begin; x < r.x_end; ++x) {
        values.push_back(px(x, y));
        at_floor += px(x, y) <= set.frames[i].floor;
      }
    }
    if (values.empty()) return;
    if (at_floor > kTransferMaxFloorFraction * values.size()) pool->clipped = true;
    std::optional<ClippedStats> stats =
        SigmaClippedStats(std::move(values), kTransferOutlierClipSigma);
    if (!stats || stats->num_used < 2) return;
    pool->sum += stats->mean;
    pool->var_sum += stats->stddev * stats->stddev / stats->num_used;
    ++pool->count;
  };
  // A pool's mean becomes the bias unless it is empty or sits on the floor (then says so).
  auto accept = [&](const Pooled& pool, const std::string& source, const char* refused) {
    if (pool.count == 0) return false;
    if (pool.clipped) {
      warnings->push_back(refused);
      return false;
    }
    bias.value = pool.sum / pool.count;
    bias.sd = std::sqrt(pool.var_sum) / pool.count;
    bias.source = source;
    return true;
  };
  {
    Pooled pool;
    bool all = n > 0;
    for (size_t i = 0; i < n && all; ++i) {
      const FitsImage& image = *set.frames[i].image;
      std::optional<std::string> text = FindString(image.header, "BIASSEC");
      std::string error;
      std::optional<PixelRegion> r =
          text ? ParseIrafSection(*text, image.pixels.nx, image.pixels.ny, &error) : std::nullopt;
      if (!r) {
        all = false;
        break;
      }
      add_region(&pool, i, *r);
    }
    if (all && accept(pool, "bias section (BIASSEC)",
                      "the bias section sits on the clipped black level: its mean is not the "
                      "bias and was not used")) {
      return bias;
    }
  }
  {
    Pooled pool;
    std::string which;
    for (size_t i = 0; i < n; ++i) {
      if (!(set.exptimes[i] == 0.0)) continue;
      add_region(&pool, i, set.frames[i].region);
      which += (which.empty() ? "" : ", ") + set.names[i];
    }
    if (accept(pool, "zero-second frames (" + which + ")",
               "the zero-second frames sit on the clipped black level: their mean is not the "
               "bias and was not used")) {
      return bias;
    }
  }
  return bias;
}

nlohmann::json TransferFramesJson(const std::vector<PtcFrameInfo>& frames) {
  using internal::JsonNumber;
  nlohmann::json out = nlohmann::json::array();
  for (const PtcFrameInfo& f : frames) {
    out.push_back({{"file", f.name},
                   {"exptime_s", JsonNumber(f.exptime_s)},
                   {"exptime_source", f.exptime_source},
                   {"black_level_clipped", f.floor_clipped},
                   {"floor_adu", JsonNumber(f.floor_adu)},
                   {"pixels_at_minimum_fraction", f.floor_pixel_fraction},
                   {"ceiling_adu", JsonNumber(f.ceiling_adu)},
                   {"ceiling_source", f.ceiling_source},
                   {"role", f.role}});
  }
  return out;
}

bool ReadTransferFrames(const std::vector<std::string>& paths, std::vector<FitsImage>* frames,
                        std::string* error) {
  frames->clear();
  for (const std::string& path : paths) {
    std::optional<FitsImage> image = ReadFitsImage(path, error);
    if (!image) return false;
    frames->push_back(std::move(*image));
  }
  return true;
}

}  // namespace ccdpsf
