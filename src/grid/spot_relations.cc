// Relations per spot across settings (spot_relations.h).
#include "ccdpsf/grid/spot_relations.h"

#include <algorithm>
#include <cmath>
#include <map>

#include "ccdpsf/random.h"

namespace ccdpsf::grid {
namespace {

// Tracks: per track, the index into result.spots of its spot in each setting (-1: none).
std::vector<std::vector<int>> Tracks(const GridResult& result, double radius) {
  const int settings = static_cast<int>(result.settings.size());
  std::vector<std::vector<int>> tracks;
  std::vector<std::pair<double, double>> where;  // each track's position
  for (int s = 0; s < settings; ++s) {
    std::vector<int> mine;
    for (int i = 0; i < static_cast<int>(result.spots.size()); ++i) {
      if (result.spots[i].setting == s) mine.push_back(i);
    }
    struct Pair {
      double d2;
      int track, spot;
    };
    std::vector<Pair> pairs;
    for (int t = 0; t < static_cast<int>(tracks.size()); ++t) {
      for (int i : mine) {
        const double dx = result.spots[i].where.x_px - where[t].first;
        const double dy = result.spots[i].where.y_px - where[t].second;
        if (dx * dx + dy * dy <= radius * radius) pairs.push_back({dx * dx + dy * dy, t, i});
      }
    }
    std::stable_sort(pairs.begin(), pairs.end(), [](const Pair& a, const Pair& b) {
      return a.d2 != b.d2 ? a.d2 < b.d2
                          : (a.track != b.track ? a.track < b.track : a.spot < b.spot);
    });
    std::map<int, bool> taken;
    for (const Pair& p : pairs) {
      if (taken[p.spot] || tracks[p.track][s] >= 0) continue;
      tracks[p.track][s] = p.spot;
      taken[p.spot] = true;
    }
    for (int i : mine) {
      if (taken[i]) continue;
      tracks.emplace_back(settings, -1);
      tracks.back()[s] = i;
      where.emplace_back(result.spots[i].where.x_px, result.spots[i].where.y_px);
    }
  }
  return tracks;
}

// The spot's measurement of `metric` as a relation point, or a gap with the reason.
trend::RelationPoint Point(const GridResult& result, const SpotEntry& e, const std::string& metric,
                           double abscissa) {
  const std::string label = result.settings[e.setting].name + " spot " + std::to_string(e.spot);
  if (!e.fitted) {
    return trend::RelationPoint::Missing(label, abscissa, "not fitted: " + e.where.refused);
  }
  if (!e.fit.ok) return trend::RelationPoint::Missing(label, abscissa, e.fit.failure);
  // As in trend: a fit that identifies only the total widths measures no CCD-only metric.
  if (e.fit.ccd_split_unidentified && trend::IsCcdOnlyMetric(metric)) {
    return trend::RelationPoint::Missing(
        label, abscissa,
        "CCD widths not identified at one focus (integrated sampling, Gaussian defocus): only "
        "the total widths are measured");
  }
  const auto draws = e.fit.draws.find(metric);
  if (draws != e.fit.draws.end() && draws->second.size() >= 2) {
    return trend::RelationPoint::FromDraws(label, abscissa, draws->second);
  }
  const auto s = e.fit.summaries.find(metric);
  if (s == e.fit.summaries.end()) {
    return trend::RelationPoint::Missing(label, abscissa, "no " + metric + " in its fit");
  }
  return trend::RelationPoint::FromGaussian(label, abscissa, s->second.map, s->second.laplace_sd);
}

// The spot's peak-pixel intensity [e-]: posterior median, else the MAP.
double PeakE(const SpotEntry& e) {
  if (!e.fitted || !e.fit.ok) return NAN;
  return std::isfinite(e.fit.peak_e.median) ? e.fit.peak_e.median : e.fit.peak_e.map;
}

}  // namespace

const std::vector<std::string>& SpotRelationMetrics() {
  static const std::vector<std::string> names = {"total_fwhm_um", "fwhm_um"};
  return names;
}

std::vector<SpotRelation> FitSpotRelations(const GridResult& result, double match_radius_px,
                                           const trend::RelationOptions& options) {
  std::vector<SpotRelation> out;
  if (result.settings.size() < 2) return out;
  // Settings by wavelength (rounded to 0.1 nm).
  std::map<long long, std::vector<int>> by_wavelength;
  for (int s = 0; s < static_cast<int>(result.settings.size()); ++s) {
    by_wavelength[std::llround(result.settings[s].wavelength_nm * 10)].push_back(s);
  }
  const std::vector<std::vector<int>> tracks = Tracks(result, match_radius_px);
  uint64_t stream = 0;
  // Relation k's resamplings from DeriveSeed(seed, k); kept when the options are valid.
  auto fit_and_keep = [&](SpotRelation r, const std::vector<trend::RelationPoint>& points) {
    trend::RelationOptions o = options;
    o.seed = DeriveSeed(options.seed, stream++);
    std::string error;
    std::optional<trend::RelationFit> fit = trend::FitRelation(r.kind, points, o, &error);
    if (!fit) return;
    r.fit = std::move(*fit);
    out.push_back(std::move(r));
  };
  for (int t = 0; t < static_cast<int>(tracks.size()); ++t) {
    const std::vector<int>& track = tracks[t];
    const SpotEntry* first = nullptr;
    for (int i : track) {
      if (i >= 0 && first == nullptr) first = &result.spots[i];
    }
    for (const std::string& metric : SpotRelationMetrics()) {
      // vs wavelength: per wavelength the setting nearest I0 in this spot's intensity.
      if (by_wavelength.size() >= 2) {
        SpotRelation r;
        r.track = t;
        r.x_px = first->where.x_px;
        r.y_px = first->where.y_px;
        r.metric = metric;
        r.kind = trend::RelationKind::kPowerLaw;
        std::vector<trend::RelationPoint> points;
        for (const auto& [key, settings] : by_wavelength) {
          int best = -1;
          double best_d = INFINITY;
          for (int s : settings) {
            if (track[s] < 0) continue;
            const double peak = PeakE(result.spots[track[s]]);
            const double d = std::isfinite(peak)
                                 ? std::fabs(std::log(peak / trend::kReferenceIntensityE))
                                 : 1e300;
            if (best < 0 || d < best_d) best = s, best_d = d;
          }
          if (best < 0) continue;  // the spot is not in any setting of this wavelength
          const SpotEntry& e = result.spots[track[best]];
          points.push_back(Point(result, e, metric, result.settings[best].wavelength_nm));
          r.spots.push_back(e.spot);
        }
        fit_and_keep(std::move(r), points);
      }
      // vs intensity, at each wavelength with two or more settings.
      for (const auto& [key, settings] : by_wavelength) {
        if (settings.size() < 2) continue;
        SpotRelation r;
        r.track = t;
        r.x_px = first->where.x_px;
        r.y_px = first->where.y_px;
        r.metric = metric;
        r.kind = trend::RelationKind::kLinear;
        r.wavelength_nm = key / 10.0;
        std::vector<trend::RelationPoint> points;
        for (int s : settings) {
          if (track[s] < 0) continue;
          const SpotEntry& e = result.spots[track[s]];
          points.push_back(Point(result, e, metric, PeakE(e)));
          r.spots.push_back(e.spot);
        }
        fit_and_keep(std::move(r), points);
      }
    }
  }
  return out;
}

}  // namespace ccdpsf::grid
