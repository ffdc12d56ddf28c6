#include "ccdpsf/trend/intensity_series.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <memory>
#include <set>
#include <utility>

#include "ccdpsf/fit/affected_widths.h"
#include "ccdpsf/metrics.h"
#include "ccdpsf/trend/relations.h"
#include "internal/text.h"

namespace ccdpsf::trend {

namespace {

// The series of `members` (the settings of one wavelength), named after its kind.
CampaignGroup Series(const std::vector<const CampaignGroup*>& members, bool through_focus) {
  CampaignGroup series;
  series.wavelength_nm = members[0]->wavelength_nm;
  series.name = internal::FormatNumber(series.wavelength_nm) +
                (through_focus ? "nm_focus_intensity_series" : "nm_intensity_series");
  series.intensity_series = true;
  series.focus_series = through_focus;
  std::set<double> positions;
  bool inputs = true;
  for (const CampaignGroup* g : members) {
    if (g->focus_series) series.member_focus_series.push_back(g->name);
    positions.insert(g->focus_positions_um.begin(), g->focus_positions_um.end());
    inputs = inputs && g->inputs.size() == g->files.size();
    for (size_t f = 0; f < g->files.size(); ++f) {
      series.files.push_back(g->files[f]);
      series.member_settings.push_back(g->name);
    }
  }
  series.focus_positions_um.assign(positions.begin(), positions.end());
  // Inputs only when every file has its own (else the fit reads the files plainly).
  for (const CampaignGroup* g : members) {
    if (inputs) series.inputs.insert(series.inputs.end(), g->inputs.begin(), g->inputs.end());
  }
  return series;
}

}  // namespace

std::vector<fit::FitEffect> TakeIntensitySeriesEffects(std::vector<fit::FitEffect>* effects) {
  std::vector<fit::FitEffect> taken;
  for (auto it = effects->begin(); it != effects->end();) {
    if (it->kind == model::EffectKind::kBrighterFatter ||
        it->kind == model::EffectKind::kBoundaryShift) {
      taken.push_back(*it);
      it = effects->erase(it);
    } else {
      ++it;
    }
  }
  return taken;
}

std::vector<CampaignGroup> IntensitySeries(const std::vector<CampaignGroup>& groups,
                                           bool one_focus_identifies) {
  // By wavelength: the through-focus series, and the single-focus settings by stage
  // position (FOCUSPOS; "none" for a setting without one, or with several).
  std::map<double, std::vector<const CampaignGroup*>> focus_series;
  std::map<double, std::map<std::string, std::vector<const CampaignGroup*>>> single;
  for (const CampaignGroup& g : groups) {
    if (!g.problem.empty() || g.intensity_series || !std::isfinite(g.wavelength_nm)) continue;
    if (g.focus_series) {
      focus_series[g.wavelength_nm].push_back(&g);
      continue;
    }
    const std::string focus = g.focus_positions_um.size() == 1
                                  ? internal::FormatNumber(g.focus_positions_um[0], 9)
                                  : std::string("none");
    single[g.wavelength_nm][focus].push_back(&g);
  }
  std::vector<CampaignGroup> out;
  std::set<double> wavelengths;
  for (const auto& [w, list] : focus_series) wavelengths.insert(w);
  for (const auto& [w, list] : single) wavelengths.insert(w);
  for (double w : wavelengths) {
    auto series = focus_series.find(w);
    auto by_focus = single.find(w);
    if (series != focus_series.end()) {
      // Through focus: the series and every single-focus setting with a stage position, all
      // on the series' focus law (the exact form of defocus_anchor.h's box).
      std::vector<const CampaignGroup*> members = series->second;
      if (by_focus != single.end()) {
        for (const auto& [focus, settings] : by_focus->second) {
          if (focus == "none") continue;
          members.insert(members.end(), settings.begin(), settings.end());
        }
      }
      if (members.size() >= 2) {
        out.push_back(Series(members, true));
        continue;
      }
    }
    if (by_focus == single.end()) continue;
    const std::vector<const CampaignGroup*>* largest = nullptr;
    for (const auto& [focus, members] : by_focus->second) {
      // Without a stage position no series can anchor the shared defocus.
      if (focus == "none" && !one_focus_identifies) continue;
      if (largest == nullptr || members.size() > largest->size()) largest = &members;
    }
    if (largest != nullptr && largest->size() >= 2) out.push_back(Series(*largest, false));
  }
  return out;
}

std::vector<std::string> SeriesMembers(const CampaignGroup& series) {
  std::vector<std::string> out;
  for (const std::string& m : series.member_settings) {
    if (std::find(out.begin(), out.end(), m) == out.end()) out.push_back(m);
  }
  return out;
}

std::string SettingDrawKey(const std::string& setting, const std::string& metric) {
  return metric + "@" + setting;
}

std::string SettingIntrinsicDrawKey(const std::string& setting, const std::string& metric) {
  return "intrinsic:" + metric + "@" + setting;
}

bool SettingKernelDraws(const fit::FitModel& model, const fit::FitResult& result,
                        const std::vector<std::string>& settings,
                        const std::vector<std::string>& focus_series, int num_draws,
                        std::map<std::string, std::vector<double>>* draws, std::string* error) {
  if (!result.have_mcmc) {
    *error = "no MCMC chain: the settings' kernel draws need one";
    return false;
  }
  if (static_cast<int>(settings.size()) != model.num_exposures()) {
    *error = "the series' fit holds " + std::to_string(model.num_exposures()) +
             " exposures, its files " + std::to_string(settings.size());
    return false;
  }
  // The member settings in order of first appearance, each with its exposures.
  std::vector<std::pair<std::string, std::vector<int>>> members;
  for (int k = 0; k < model.num_exposures(); ++k) {
    auto it = std::find_if(members.begin(), members.end(),
                           [&](const auto& m) { return m.first == settings[k]; });
    if (it == members.end()) {
      members.push_back({settings[k], {}});
      it = members.end() - 1;
    }
    it->second.push_back(k);
  }
  const fit::SamplerResult& c = result.chain;
  const int dim = model.dim();
  const double pixel_um = model.stamps()[0].info.pixel_um;
  std::unique_ptr<fit::FitEvaluator> evaluator = model.NewEvaluator();
  for (const size_t s : c.ThinnedStates(num_draws)) {
    // Where the settings' intensities are measured (fit.h PeakTheta): centred spots, a
    // through-focus series at best focus, a single-focus setting at its own defocus.
    const std::vector<double> at_best = fit::PeakTheta(model, &c.chain[s * dim]);
    std::vector<double> at_own = at_best;
    at_own[fit::kDefocusPx] = c.chain[s * dim + fit::kDefocusPx];
    for (const auto& [setting, exposures] : members) {
      const bool series =
          std::find(focus_series.begin(), focus_series.end(), setting) != focus_series.end();
      const double* theta = series ? at_best.data() : at_own.data();
      // The setting's widths: the mean over its exposures (one intensity, nearly one width).
      double sx = 0.0, sy = 0.0;
      for (int k : exposures) {
        fit::AffectedWidths w;
        if (!fit::AffectedKernelWidths(model, evaluator.get(), theta, k, &w)) {
          *error = "a chain state's spot of exposure " + std::to_string(k) + " cannot be drawn";
          return false;
        }
        sx += w.ccd_sigma_x_px / exposures.size();
        sy += w.ccd_sigma_y_px / exposures.size();
      }
      const PsfMetrics affected = GaussianMetrics(sx, sy, pixel_um);
      const PsfMetrics intrinsic =
          GaussianMetrics(theta[fit::kCcdSigmaXPx], theta[fit::kCcdSigmaYPx], pixel_um);
      auto values = [](const PsfMetrics& m) {
        return std::map<std::string, double>{{"fwhm_um", m.fwhm_um},
                                             {"fwhm_x_um", m.fwhm_x_um},
                                             {"fwhm_y_um", m.fwhm_y_um},
                                             {"r2_px2", m.r2_px2},
                                             {"ellipticity", m.ellipticity}};
      };
      const std::map<std::string, double> at_signal = values(affected), at_zero = values(intrinsic);
      for (const std::string& metric : TrendMetricNames()) {
        if (!IsCcdOnlyMetric(metric)) continue;
        (*draws)[SettingDrawKey(setting, metric)].push_back(at_signal.at(metric));
        (*draws)[SettingIntrinsicDrawKey(setting, metric)].push_back(at_zero.at(metric));
      }
    }
  }
  return true;
}

}  // namespace ccdpsf::trend
