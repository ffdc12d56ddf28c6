// The brighter-fatter slope in a campaign: the single-focus settings of one wavelength,
// fitted jointly, give the intensity relation of the CCD kernel itself.
//
// Two signal-dependent effects go to the series (TakeIntensitySeriesEffects): brighter_fatter
// (the paper's empirical law, widths sigma_0 + b I) and boundary_shift (pixel boundaries
// moved by the collected charge, coefficients a_ij). Either one's model holds the kernel at
// zero signal, the INTRINSIC kernel, in ccd_sigma_x_px / ccd_sigma_y_px; the kernel each
// setting's exposures show is that kernel widened by their own charge, the AFFECTED kernel
// (fit/affected_widths.h: for brighter_fatter sigma_0 + b I exactly, for boundary_shift the
// width whose Gaussian gives the exposure's image the second moment the boundary shifts give
// it).
//
// Why: a setting holds one intensity, where the slope b of the widths' growth
// sigma(I) = sigma_0 + b I (model/effects.h, brighter_fatter) is exactly a change of the CCD
// widths, so a setting cannot fit it. The settings of one wavelength taken at one stage
// position share the optics, the defocus and the kernel; fitted as one joint group (an
// "intensity series": per-exposure positions and fluxes, sigma_0, b and the defocus
// shared), they measure sigma_0 and b. The settings are still fitted on their own as well,
// without the slope (their total_* metrics and their points in the wavelength relations).
//
// The relations: each member setting's point is the series' posterior of the CCD-only metrics
// of the affected widths of its exposures where its intensity is measured (fit.h PeakTheta:
// centred, at best focus; fit::AffectedKernelWidths, averaged over the setting's exposures),
// at the setting's own intensity (its own fit's peak_e, the abscissa of every intensity
// relation): trend.json's `relations.<metric>_vs_intensity`, with brighter_fatter the paper's
// relation. Beside them the same points of the intrinsic kernel (the fitted ccd_sigma_*,
// shared by every setting of the series, so that relation's slope is 0 on every draw: the
// model's statement that the intrinsic kernel does not depend on the signal; its intercept is
// the intrinsic kernel's metric with the series' interval): `relations_intrinsic`.
// The points come from one posterior, draw j of each from state j, and the relation is
// resampled state by state (relations.h, joint_points): its intervals are the joint fit's.
//
// The assumption the report states: the settings of one wavelength share the kernel and
// the optics: through-focus series the focus law, single-focus settings at one stage
// position the defocus (as a setting's exposures do in its own joint fit).
#ifndef CCDPSF_TREND_INTENSITY_SERIES_H_
#define CCDPSF_TREND_INTENSITY_SERIES_H_

#include <string>
#include <vector>

#include "ccdpsf/fit/fit.h"
#include "ccdpsf/fit/fit_model.h"
#include "ccdpsf/trend/campaign.h"

namespace ccdpsf::trend {

// Takes the signal-dependent effects (brighter_fatter, boundary_shift) out of `effects` and
// returns them: a setting at one intensity cannot fit them (there they are a change of the
// CCD widths, exactly for brighter_fatter, nearly for boundary_shift), so they are fitted by
// the intensity series only.
std::vector<fit::FitEffect> TakeIntensitySeriesEffects(std::vector<fit::FitEffect>* effects);

// The intensity series of a campaign, one per wavelength at most: when the wavelength has a
// through-focus series, its series and its single-focus settings with a stage position
// (FOCUSPOS), two or more in all ("<wavelength>nm_focus_intensity_series": the series
// identify the CCD widths, and all share the focus law of the projector, rate |z - z0|, so
// each setting's defocus is rate |z - z0| at its own position: the exact joint form of
// defocus_anchor.h's box); else its single-focus settings at one stage position, the
// largest such set of two or more
// ("<wavelength>nm_intensity_series"; settings without a stage position only when
// `one_focus_identifies`, i.e. the model splits the CCD widths from the defocus at one focus:
// otherwise nothing could anchor their shared defocus). Groups with a problem are left out.
std::vector<CampaignGroup> IntensitySeries(const std::vector<CampaignGroup>& groups,
                                           bool one_focus_identifies);

// The series' member settings, each once, in the order of its files.
std::vector<std::string> SeriesMembers(const CampaignGroup& series);

// The keys under which a series' GroupResult::draws holds `metric` at member `setting`: of
// the affected kernel, and of the intrinsic one.
std::string SettingDrawKey(const std::string& setting, const std::string& metric);
std::string SettingIntrinsicDrawKey(const std::string& setting, const std::string& metric);

// The CCD-only trend metrics (relations.h TrendMetricNames) at each member setting of the
// series, one value per chain state of SamplerResult::ThinnedStates(num_draws) (as
// group_fit.cc thins the chain for the other draws), into *draws under SettingDrawKey (the
// affected kernel) and SettingIntrinsicDrawKey (the intrinsic one). `settings`
// names the member setting of each exposure of `model`, `focus_series` the members that are
// through-focus series (their kernel at best focus, where their intensity is measured; the
// others' at their own defocus). False, with the reason, when the chain is absent or a
// state's spot cannot be drawn.
bool SettingKernelDraws(const fit::FitModel& model, const fit::FitResult& result,
                        const std::vector<std::string>& settings,
                        const std::vector<std::string>& focus_series, int num_draws,
                        std::map<std::string, std::vector<double>>* draws, std::string* error);

}  // namespace ccdpsf::trend

#endif  // CCDPSF_TREND_INTENSITY_SERIES_H_
