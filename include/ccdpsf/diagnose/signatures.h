// What each candidate of `ccdpsf diagnose` leaves in the residuals when it is missing (the
// statistics of statistics.h it moves), and what data would tell two candidates apart: the
// tables behind the check that an added candidate explains the misfit it was chosen for.
//
// A statistic is flagged when its predictive p-value is below kFlaggedP, and back within noise
// when it is at least kWithinNoiseP (a gap between the two, so that a statistic near the edge
// does not flip the verdict). chi2_per_dof belongs to every signature: a candidate that leaves
// the overall misfit flagged has not explained it.
#ifndef CCDPSF_DIAGNOSE_SIGNATURES_H_
#define CCDPSF_DIAGNOSE_SIGNATURES_H_

#include <string>
#include <vector>

namespace ccdpsf::diagnose {

constexpr double kFlaggedP = 1e-3;
constexpr double kWithinNoiseP = 0.01;
// Runner-ups significant within this delta BIC of the winner make its name ambiguous: less
// than "strong" evidence between them on the scale of Kass & Raftery (1995).
constexpr double kAmbiguousDeltaBic = 6.0;
// An adopted candidate explains only on at least "strong" evidence on the same scale: one
// adopted with delta BIC above -6 helped the likelihood a little and is partial. (Seen on
// brighter-fatter series from an independent simulator: after brighter_fatter, a halo or a
// background adopted at delta BIC -0.7 to -3 mopped up the shape the catalogue's linear
// width growth misses.)
constexpr double kStrongDeltaBic = -6.0;

// The statistics `name` (a catalogue effect or a model alternative) moves; empty for an
// unknown name.
const std::vector<std::string>& SignatureStatistics(const std::string& name);

// One line: the data that would separate candidates `a` and `b` (either order).
std::string SeparatingData(const std::string& a, const std::string& b);

}  // namespace ccdpsf::diagnose

#endif  // CCDPSF_DIAGNOSE_SIGNATURES_H_
