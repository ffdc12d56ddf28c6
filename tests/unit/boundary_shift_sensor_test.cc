// The boundary-shift model against physics it did not make: the charge a bright spot's
// collected charge moves between pixels, as the photon-shooting reference sensor
// (tests/support/reference_sensor.py: every electron assigned against boundaries displaced
// by the charge collected before it, in 1000 batches) makes it, against ApplyBoundaryShift on
// the same spot with the sensor's coefficients.
//
// The sensor's numbers are testdata/reference_sensor/boundary_shift_pixels.json (written by
// tests/support/boundary_shift_pixels.py: the mean over 12 seeds of the difference between a
// 5.9e5 e- spot drawn with and without the shift, and its standard error). The model is given
// the sensor's a_10, a_01, a_11, the mean of its a_20 and a_02 as a_far (the model's far law is
// the same along both axes, the sensor's is not), and the anisotropy eta = (B_x - B_y) /
// (B_x + B_y) of the sensor's boundary stiffnesses.
//
// What is held, and why these tolerances (each also allows 3 standard errors of the sensor's
// mean; measured on the default sensor and on the isotropic one):
//   the central pixel's loss within 5 % (measured: -3.1 % and -2.9 %, the model losing a
//     little less): the charge the spot's own peak sheds, set by a_00 and so by the far
//     lags' law through the sum rule (with the far power 3 instead of 4 the model lost 11 %
//     more: docs/conventions.md, boundary shifts);
//   the four edge neighbours' gain, along x and along y, within 7 %, and the ratio of the
//     gains along y and along x within 5 %: the shift of the nearest boundaries and its
//     anisotropy (measured: x -1.7 % and -3.5 %, y -4.6 % and -3.0 %, the ratio -2.9 % and
//     +0.6 %);
//   the four diagonals' gain within 6 % (measured: -2.2 % and -2.3 %): the corner term, the
//     patch beyond two displaced sides of one pixel given to the diagonal neighbour as the
//     sensor gives it. Without it (first order in the shifts only) the diagonals came out
//     14 % low and the edges 3-9 % high.
#include <cmath>
#include <fstream>
#include <string>
#include <vector>

#include "ccdpsf/model/boundary_shift.h"
#include "ccdpsf/model/effects.h"
#include "ccdpsf/model/renderer.h"
#include "gtest/gtest.h"
#include "support/boundary_densities.h"
#include "nlohmann/json.hpp"

namespace ccdpsf::model {
namespace {

// The spot's charge moved by the shift, model side: the paper's spot of `flux` e- centred on
// pixel (10, 10) of a 21 x 21 grid (the sensor's pixel (24, 24) of its 48 x 48 frame).
std::vector<double> ModelMoved(const BoundaryShiftParams& a, double flux) {
  SpotParams p;
  p[kFlux] = flux;
  p[kCentreX] = 10.0;
  p[kCentreY] = 10.0;
  p[kAiryRadius] = 0.47;
  p[kDefocus] = 0.41;
  p[kCcdSigmaX] = 0.291;
  p[kCcdSigmaY] = 0.335;
  const SpotRenderer renderer{ModelOptions()};
  const PixelGrid grid;
  DualImage image{grid.nx, grid.ny, 0, std::vector<double>(grid.size())};
  renderer.Render(p, grid, image.data.data(), nullptr);
  const BoundaryDensities densities = testing_support::DrawBoundaryDensities(renderer, p, grid);
  DualImage shifted = image;
  ApplyBoundaryShift(a, densities, BoundaryShiftWindow(10, 10, grid.nx, grid.ny), EffectChannels(),
                     &shifted);
  std::vector<double> moved(grid.size());
  for (int q = 0; q < grid.size(); ++q) moved[q] = shifted.data[q] - image.data[q];
  return moved;
}

struct Sums {
  double centre = 0.0, centre_sem = 0.0;
  double edge_x = 0.0, edge_y = 0.0, edge_x_sem = 0.0, edge_y_sem = 0.0;
  double diagonal = 0.0, diagonal_sem = 0.0;
};

// The centre, its x and y edge neighbours and its diagonals from a (2 h + 1)^2 table centred
// on the spot, [row][column], with the standard errors (added in quadrature) where given.
Sums SumsOf(const std::vector<std::vector<double>>& v,
            const std::vector<std::vector<double>>* sem, int h) {
  Sums s;
  auto at = [&](const std::vector<std::vector<double>>& t, int di, int dj) {
    return t[h + dj][h + di];
  };
  auto add = [&](double* value, double* error, int di, int dj) {
    *value += at(v, di, dj);
    if (sem != nullptr) *error = std::hypot(*error, at(*sem, di, dj));
  };
  add(&s.centre, &s.centre_sem, 0, 0);
  add(&s.edge_x, &s.edge_x_sem, -1, 0);
  add(&s.edge_x, &s.edge_x_sem, 1, 0);
  add(&s.edge_y, &s.edge_y_sem, 0, -1);
  add(&s.edge_y, &s.edge_y_sem, 0, 1);
  for (int dj : {-1, 1}) {
    for (int di : {-1, 1}) add(&s.diagonal, &s.diagonal_sem, di, dj);
  }
  return s;
}

TEST(BoundaryShiftSensor, MovesTheChargeThePhotonShootingSensorMoves) {
  std::ifstream in(std::string(CCDPSF_TESTDATA) + "/reference_sensor/boundary_shift_pixels.json");
  ASSERT_TRUE(in.good());
  const nlohmann::json data = nlohmann::json::parse(in);
  const int h = data["half"].get<int>();
  const double flux = data["flux_e"].get<double>();
  for (const auto& [name, c] : data["cases"].items()) {
    SCOPED_TRACE(name);
    const auto& a = c["a"];
    const BoundaryShiftParams params{
        a["a_10"].get<double>(), a["a_01"].get<double>(), a["a_11"].get<double>(),
        0.5 * (a["a_20"].get<double>() + a["a_02"].get<double>()), c["anisotropy"].get<double>()};
    const auto sensor_v = c["moved_e"].get<std::vector<std::vector<double>>>();
    const auto sensor_sem = c["moved_sem_e"].get<std::vector<std::vector<double>>>();
    const Sums sensor = SumsOf(sensor_v, &sensor_sem, h);

    const std::vector<double> moved = ModelMoved(params, flux);
    std::vector<std::vector<double>> model_v(2 * h + 1, std::vector<double>(2 * h + 1));
    for (int j = -h; j <= h; ++j) {
      for (int i = -h; i <= h; ++i) model_v[h + j][h + i] = moved[(10 + j) * 21 + (10 + i)];
    }
    const Sums model = SumsOf(model_v, nullptr, h);

    EXPECT_LT(sensor.centre, -1.5e4) << "a loss the comparison can resolve";
    EXPECT_NEAR(model.centre, sensor.centre,
                0.05 * std::fabs(sensor.centre) + 3.0 * sensor.centre_sem);
    EXPECT_NEAR(model.edge_x, sensor.edge_x, 0.07 * sensor.edge_x + 3.0 * sensor.edge_x_sem);
    EXPECT_NEAR(model.edge_y, sensor.edge_y, 0.07 * sensor.edge_y + 3.0 * sensor.edge_y_sem);
    const double ratio = sensor.edge_y / sensor.edge_x;
    const double ratio_sem =
        ratio * std::hypot(sensor.edge_y_sem / sensor.edge_y, sensor.edge_x_sem / sensor.edge_x);
    EXPECT_NEAR(model.edge_y / model.edge_x, ratio, 0.05 * ratio + 3.0 * ratio_sem);
    EXPECT_NEAR(model.diagonal, sensor.diagonal,
                0.06 * sensor.diagonal + 3.0 * sensor.diagonal_sem);
  }
}

}  // namespace
}  // namespace ccdpsf::model
