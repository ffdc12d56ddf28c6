#include "ccdpsf/trend/defocus_anchor.h"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "ccdpsf/fit/fit.h"
#include "internal/text.h"

namespace ccdpsf::trend {
namespace {

// Series and setting count as one wavelength within this [nm] (as the trend's relations do).
constexpr double kSameWavelengthNm = 0.5;

// The draws of rate |z - z0| [px] of a fitted series at stage position z, or empty when the
// series kept no draws of both parameters (a run without MCMC, an old store).
std::vector<double> DefocusDraws(const GroupResult& series, double z) {
  const auto rate = series.draws.find("defocus_rate_px_per_um");
  const auto z0 = series.draws.find("best_focus_um");
  if (rate == series.draws.end() || z0 == series.draws.end() ||
      rate->second.size() != z0->second.size()) {
    return {};
  }
  std::vector<double> out(rate->second.size());
  for (size_t i = 0; i < out.size(); ++i) out[i] = rate->second[i] * std::fabs(z - z0->second[i]);
  return out;
}

}  // namespace

bool ParseAnchorScope(const std::string& text, AnchorScope* scope) {
  for (AnchorScope s :
       {AnchorScope::kOff, AnchorScope::kSameWavelength, AnchorScope::kAnyWavelength}) {
    if (text == ToString(s)) {
      *scope = s;
      return true;
    }
  }
  return false;
}

std::string ToString(AnchorScope scope) {
  switch (scope) {
    case AnchorScope::kOff:
      return "off";
    case AnchorScope::kSameWavelength:
      return "same_wavelength";
    case AnchorScope::kAnyWavelength:
      return "any_wavelength";
  }
  return "?";
}

std::vector<std::string> AnchorDefocus(const std::vector<GroupResult>& series,
                                       const fit::FitModelOptions& model, AnchorScope scope,
                                       std::vector<CampaignGroup>* groups) {
  std::vector<std::string> notes;
  if (scope == AnchorScope::kOff || series.empty()) return notes;
  if (model.model.sampling != model::Sampling::kIntegrated ||
      model.model.defocus != model::DefocusKind::kGaussian) {
    notes.push_back(
        "single-focus settings not anchored by the through-focus series: anchoring needs "
        "integrated sampling with a Gaussian defocus (the series' own model)");
    return notes;
  }
  int anchored = 0, outside = 0, without_draws = 0;
  for (CampaignGroup& g : *groups) {
    g.defocus_anchor.reset();
    if (g.focus_series || !g.problem.empty() || g.focus_positions_um.size() != 1) continue;
    const double z = g.focus_positions_um[0];
    // Usable series: fitted, with draws of a converged chain, the setting's position inside
    // the scanned range, at the same wavelength unless any is allowed; the nearest in
    // wavelength first.
    const GroupResult* best = nullptr;
    bool in_range = false, with_draws = false;
    for (const GroupResult& s : series) {
      const double dl = std::fabs(s.group.wavelength_nm - g.wavelength_nm);
      if (!s.ok || (scope == AnchorScope::kSameWavelength && !(dl <= kSameWavelengthNm))) {
        continue;
      }
      const std::vector<double>& zs = s.group.focus_positions_um;
      if (zs.empty() || z < zs.front() || z > zs.back()) continue;
      in_range = true;
      if (!s.converged || DefocusDraws(s, z).empty()) continue;
      with_draws = true;
      if (best == nullptr || dl < std::fabs(best->group.wavelength_nm - g.wavelength_nm)) {
        best = &s;
      }
    }
    if (best == nullptr) {
      if (!in_range) {
        // Only settings that some series in scope could have anchored count.
        for (const GroupResult& s : series) {
          const double dl = std::fabs(s.group.wavelength_nm - g.wavelength_nm);
          if (s.ok && (scope == AnchorScope::kAnyWavelength || dl <= kSameWavelengthNm)) {
            ++outside;
            break;
          }
        }
      } else if (!with_draws) {
        ++without_draws;
      }
      continue;
    }
    fit::Summary box;
    FillPosterior(DefocusDraws(*best, z), &box);
    DefocusAnchor a;
    a.series = best->group.name;
    a.series_wavelength_nm = best->group.wavelength_nm;
    a.focus_position_um = z;
    a.median_px = box.median;
    a.lower_px = std::max(box.lo997, model.priors.defocus_px[0]);
    a.upper_px = std::min(box.hi997, model.priors.defocus_px[1]);
    if (!(a.upper_px > a.lower_px)) {
      notes.push_back(g.name + ": not anchored: the series " + a.series +
                      " puts the defocus at z = " + internal::FormatNumber(z) + " um in [" +
                      internal::FormatNumber(box.lo997) + ", " + internal::FormatNumber(box.hi997) +
                      "] px, outside the defocus prior");
      continue;
    }
    g.defocus_anchor = a;
    ++anchored;
  }
  if (anchored > 0) {
    notes.push_back(
        std::to_string(anchored) +
        " single-focus setting(s) anchored: each fitted with its defocus in the 99.73 % "
        "interval of rate |z - z0| that a through-focus series gives at its stage position "
        "(FOCUSPOS), so their CCD widths are identified. Assumed: the same optics and focus "
        "law as the series" +
        (scope == AnchorScope::kAnyWavelength
             ? ", also across wavelengths (a chromatic shift of best focus would bias it)"
             : ", at the same wavelength") +
        "; the box keeps the series' range, not its shape (docs/trust.md, anchoring the defocus)");
  }
  if (without_draws > 0) {
    notes.push_back(std::to_string(without_draws) +
                    " single-focus setting(s) with one stage position not anchored: the "
                    "through-focus series that covers it has no posterior draws of a converged "
                    "MCMC (run without --nomcmc, or see the series' fit report)");
  }
  if (outside > 0) {
    notes.push_back(std::to_string(outside) +
                    " single-focus setting(s) with one stage position not anchored: outside the "
                    "scanned range of every usable through-focus series (the defocus law is not "
                    "extrapolated)");
  }
  return notes;
}

std::vector<GroupResult> FitCampaignGroups(std::vector<CampaignGroup> groups,
                                           const GroupFitOptions& options, AnchorScope scope,
                                           const GroupProgress& progress,
                                           std::vector<std::string>* notes) {
  const int total = static_cast<int>(groups.size());
  std::vector<int> series_at;
  for (int i = 0; i < total; ++i) {
    // (An intensity series of through-focus series anchors nothing: its members do.)
    if (groups[i].focus_series && !groups[i].intensity_series) series_at.push_back(i);
  }
  if (scope == AnchorScope::kOff || series_at.empty()) return FitGroups(groups, options, progress);
  // Each single-focus setting waits for the series in its scope (AnchorDefocus looks at no
  // other), and is anchored by them as soon as they are fitted: no barrier between the
  // series and the settings, so two workers stay busy while the last series runs.
  GroupSchedule schedule;
  schedule.after.resize(total);
  for (int g = 0; g < total; ++g) {
    if (groups[g].focus_series) continue;
    for (int s : series_at) {
      if (scope == AnchorScope::kAnyWavelength ||
          std::fabs(groups[s].wavelength_nm - groups[g].wavelength_nm) <= kSameWavelengthNm) {
        schedule.after[g].push_back(s);
      }
    }
  }
  schedule.prepare = [&](int g, const std::vector<GroupResult>& results, CampaignGroup* group) {
    if (group->focus_series) return;
    std::vector<GroupResult> series;
    for (int s : schedule.after[g]) series.push_back(results[s]);
    std::vector<CampaignGroup> one = {*group};
    AnchorDefocus(series, options.config.model, scope, &one);
    *group = one[0];
  };
  std::vector<GroupResult> results = FitGroups(groups, options, progress, &schedule);
  // The campaign's notes, from every series at once: the anchors this sets are the ones each
  // setting was fitted with (the same series in scope, in the same order).
  std::vector<GroupResult> series;
  for (int i : series_at) series.push_back(results[i]);
  const std::vector<std::string> n = AnchorDefocus(series, options.config.model, scope, &groups);
  if (notes != nullptr) notes->insert(notes->end(), n.begin(), n.end());
  return results;
}

}  // namespace ccdpsf::trend
