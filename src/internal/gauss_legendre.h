// Gauss-Legendre quadrature nodes and weights on [-1, 1].
#ifndef CCDPSF_INTERNAL_GAUSS_LEGENDRE_H_
#define CCDPSF_INTERNAL_GAUSS_LEGENDRE_H_

#include <vector>

namespace ccdpsf::internal {

// n-point rule: integrates polynomials of degree <= 2n - 1 exactly. Nodes ascending.
// Results for each n are cached; the returned reference stays valid for the program's life.
struct GaussLegendreRule {
  std::vector<double> nodes;
  std::vector<double> weights;
};
const GaussLegendreRule& GaussLegendre(int n);

}  // namespace ccdpsf::internal

#endif  // CCDPSF_INTERNAL_GAUSS_LEGENDRE_H_
