// Settings taken at the same stage position share the defocus: a through-focus series
// anchors it for the single-focus settings of its campaign.
//
// Why: at one focus, with a Gaussian defocus in integrated sampling, the data fix only the
// total widths sqrt(sigma_f^2 + sigma_ccd^2) (docs/trust.md, single focus); the CCD widths
// follow once sigma_f is known. A through-focus series measures the defocus law
// sigma_f(z) = rate |z - z0| of the projector (fit_model.h). A single-focus setting whose
// exposures all carry one stage position z (FOCUSPOS) inside the series' scanned range then
// has sigma_f = rate |z - z0| too.
//
// The approximation (stated in every anchored group's notes and in the trend report): the
// anchored group is fitted alone, with the flat defocus prior replaced by the box
// [lower, upper] = the 0.135th and 99.865th percentiles of rate |z - z0| over the series'
// posterior draws (its central 99.73 %), intersected with the configured defocus prior. The
// exact answer is one joint fit of the series and the setting sharing (rate, z0); the box
// keeps all of the series' plausible defocus values and none of its shape, so the anchored
// CCD widths are at most slightly wider than the joint fit's, never narrower
// (tests/unit/defocus_anchor_test.cc compares the two on a small case). The series and the
// setting are assumed to share the optics and the focus law: the same wavelength (within
// 0.5 nm) by default; with AnchorScope::kAnyWavelength a series at another wavelength may
// anchor (geometric defocus does not depend on the wavelength, but a chromatic shift of best
// focus would bias it; the notes say so).
//
// Only for integrated sampling with a Gaussian defocus (the model the series is fitted
// with); a setting that is itself a series, has no or several stage positions, lies outside
// every usable series' scanned range, or finds no fitted series with posterior draws is
// fitted as before.
#ifndef CCDPSF_TREND_DEFOCUS_ANCHOR_H_
#define CCDPSF_TREND_DEFOCUS_ANCHOR_H_

#include <string>
#include <vector>

#include "ccdpsf/fit/fit_model.h"
#include "ccdpsf/trend/campaign.h"
#include "ccdpsf/trend/group_fit.h"

namespace ccdpsf::trend {

enum class AnchorScope { kOff, kSameWavelength, kAnyWavelength };
// "off", "same_wavelength", "any_wavelength".
bool ParseAnchorScope(const std::string& text, AnchorScope* scope);
std::string ToString(AnchorScope scope);

// Sets group.defocus_anchor on every group of `groups` that a fitted series in `series`
// anchors (see above), choosing the series nearest in wavelength, then the first in order.
// `model` is the campaign's fit model (sampling and defocus kind; the configured defocus
// prior). Returns the campaign-level notes (what was anchored, or why nothing could be).
std::vector<std::string> AnchorDefocus(const std::vector<GroupResult>& series,
                                       const fit::FitModelOptions& model, AnchorScope scope,
                                       std::vector<CampaignGroup>* groups);

// The whole campaign's fits: the through-focus series first, and each other group as soon
// as the series in its scope are fitted, anchored by them where AnchorDefocus allows (a
// GroupSchedule of FitGroups). Results are in the order of `groups`,
// each group's MCMC seed that of its position (as FitGroups gives it); `progress` counts
// over all groups. `notes` receives AnchorDefocus's notes.
std::vector<GroupResult> FitCampaignGroups(std::vector<CampaignGroup> groups,
                                           const GroupFitOptions& options, AnchorScope scope,
                                           const GroupProgress& progress,
                                           std::vector<std::string>* notes);

}  // namespace ccdpsf::trend

#endif  // CCDPSF_TREND_DEFOCUS_ANCHOR_H_
