// The diagnose signatures table is keyed by name: an effect added to the catalogue without an
// entry would silently have no signature, and diagnose could never say it explains a misfit.
#include "ccdpsf/diagnose/signatures.h"

#include <algorithm>
#include <string>

#include <gtest/gtest.h>

#include "ccdpsf/diagnose/alternatives.h"
#include "ccdpsf/model/effects.h"

namespace ccdpsf::diagnose {
namespace {

TEST(Signatures, EveryCandidateHasOneThatJudgesTheOverallMisfit) {
  std::vector<std::string> names;
  for (model::EffectKind kind : model::AllEffectKinds()) names.push_back(model::ToString(kind));
  for (AlternativeKind kind : AllAlternatives()) names.push_back(ToString(kind));
  for (const std::string& name : names) {
    const std::vector<std::string>& signature = SignatureStatistics(name);
    ASSERT_FALSE(signature.empty()) << name << " has no signature";
    // chi2_per_dof belongs to every signature (signatures.h).
    EXPECT_NE(std::find(signature.begin(), signature.end(), "chi2_per_dof"), signature.end())
        << name;
  }
  EXPECT_TRUE(SignatureStatistics("no_such_effect").empty());
}

TEST(Signatures, TheTwoBrighterFatterDescriptionsNameWhatSeparatesThem) {
  // Boundary shifts leave flats correlated, the empirical law does not: the flats must be
  // named, in either order of the pair.
  for (const auto& [a, b] : {std::pair<std::string, std::string>{"boundary_shift",
                                                                   "brighter_fatter"},
                             {"brighter_fatter", "boundary_shift"}}) {
    EXPECT_NE(SeparatingData(a, b).find("flat"), std::string::npos) << SeparatingData(a, b);
  }
  // The edge neighbours against the diagonals is what the boundary shift moves in a spot.
  const std::vector<std::string>& shift = SignatureStatistics("boundary_shift");
  EXPECT_NE(std::find(shift.begin(), shift.end(), "neighbour_z"), shift.end());
}

}  // namespace
}  // namespace ccdpsf::diagnose
