// Residual stacks (diagnose/statistics.h): the split by intensity.
#include "ccdpsf/diagnose/statistics.h"

#include <cmath>
#include <random>

#include "gtest/gtest.h"

namespace ccdpsf::diagnose {
namespace {

// A 9 x 9 exposure with unit-normal residuals, data = model + residual, every pixel valid,
// centred on the stamp's centre pixel (so it lands on the stack unshifted).
ExposureResidual Synthetic(double peak_e, std::mt19937_64& engine) {
  std::normal_distribution<double> normal;
  ExposureResidual e;
  e.data_e = e.model_e = e.normalised = Image(9, 9);
  e.valid.assign(81, 1);
  for (size_t q = 0; q < 81; ++q) {
    e.model_e.data[q] = 100.0 + q;
    e.normalised.data[q] = normal(engine);
    e.data_e.data[q] = e.model_e.data[q] + 10.0 * e.normalised.data[q];
  }
  e.centre_x = 4.1;
  e.centre_y = 3.9;
  e.peak_e = peak_e;
  e.flux_e = 2.7 * peak_e;  // classes go by the fitted intensity; one PSF: proportional
  return e;
}

TEST(Statistics, StacksAreSplitByIntensityClass) {
  std::mt19937_64 engine(5);
  // Out of order on purpose. Classes (by the fitted intensity, here proportional to the
  // peaks): a class starts where it exceeds 1.25 x the class's lowest: {1.0e5, 1.2e5}, {1.3e5} (1.3 > 1.25), {4.0e5}.
  const std::vector<double> peaks = {1.3e5, 1.0e5, 4.0e5, 1.2e5};
  std::vector<ExposureResidual> residuals;
  for (double p : peaks) residuals.push_back(Synthetic(p, engine));
  const ResidualStatistics st = ComputeStatistics(residuals, 5);
  ASSERT_EQ(st.by_intensity.size(), 3u);
  EXPECT_EQ(st.by_intensity[0].exposures, 2);
  EXPECT_EQ(st.by_intensity[0].peak_min_e, 1.0e5);
  EXPECT_EQ(st.by_intensity[0].peak_max_e, 1.2e5);
  EXPECT_EQ(st.by_intensity[1].exposures, 1);
  EXPECT_EQ(st.by_intensity[1].peak_min_e, 1.3e5);
  EXPECT_EQ(st.by_intensity[2].peak_max_e, 4.0e5);
  for (size_t q = 0; q < 81; ++q) {
    // One-exposure classes are that exposure (centred: no shift).
    EXPECT_NEAR(st.by_intensity[1].stack.normalised.data[q], residuals[0].normalised.data[q],
                1e-12);
    EXPECT_NEAR(st.by_intensity[2].stack.residual.data[q],
                residuals[2].data_e.data[q] - residuals[2].model_e.data[q], 1e-9);
    // Two: the sum / sqrt(2).
    EXPECT_NEAR(
        st.by_intensity[0].stack.normalised.data[q],
        (residuals[1].normalised.data[q] + residuals[3].normalised.data[q]) / std::sqrt(2.0),
        1e-12);
    // The classes add up to the stack of all exposures.
    double residual = 0.0, normalised = 0.0;
    for (const IntensityStack& c : st.by_intensity) {
      residual += c.stack.residual.data[q];
      normalised += c.stack.normalised.data[q] * std::sqrt(c.stack.count.data[q]);
    }
    EXPECT_NEAR(residual, st.stack.residual.data[q], 1e-9);
    EXPECT_NEAR(normalised, st.stack.normalised.data[q] * 2.0, 1e-12);
  }
  // One intensity (within 1.25): one class, the same as the whole stack.
  std::vector<ExposureResidual> one = {Synthetic(1.0e5, engine), Synthetic(1.2e5, engine)};
  const ResidualStatistics single = ComputeStatistics(one, 5);
  ASSERT_EQ(single.by_intensity.size(), 1u);
  EXPECT_EQ(single.by_intensity[0].stack.normalised.data, single.stack.normalised.data);
}

}  // namespace
}  // namespace ccdpsf::diagnose
