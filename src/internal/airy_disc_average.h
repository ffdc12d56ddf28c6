// The unit-flux Airy pattern averaged over a disc: the spot of a geometric (pillbox) defocus
// before the CCD kernel, S = Airy (*) pillbox, at one point.
//
// A disc average is a flux through the disc's edge (the divergence theorem), so it needs one
// integral round the circle instead of one over the disc. The Airy intensity I(rho) (unit
// flux, wavenumber k = pi Rz / r) is the divergence of the radial field
//   Phi(p) = E(|p|) / (2 pi |p|^2) p,   E(rho) = 1 - J0(k rho)^2 - J1(k rho)^2,
// E being the energy encircled within rho (Born & Wolf 8.5.2). For a disc of radius R whose
// centre is d from the Airy centre, with rho^2 = d^2 + R^2 + 2 d R cos(theta):
//   S      = (1 / (pi R^2)) closed-integral Phi . n dl = (1 / (pi R)) <E(rho) (d cos + R) / rho^2>,
//   dS/dR  = (2 / R) (<I(rho)> - S)          (the edge moves outwards),
//   dS/dd  = (2 / R) <I(rho) cos(theta)>     (the disc average of dI/dx),
//   dS/dk  = (2 S + d dS/dd + R dS/dR) / k   (S = k^2 F(k d, k R) by scaling),
// where <.> is the mean over theta in [0, 2 pi). Each integrand is an entire, periodic function
// of theta, so the midpoint rule converges geometrically once its node count passes the
// highest angular frequency, ~2 k R (E and I oscillate as cos(2 k rho), and rho moves by up to
// R per radian); they are even in theta, so nodes on [0, pi] suffice.
#ifndef CCDPSF_INTERNAL_AIRY_DISC_AVERAGE_H_
#define CCDPSF_INTERNAL_AIRY_DISC_AVERAGE_H_

#include <vector>

namespace ccdpsf::internal {

// The angular rule for one (k, R): midpoints theta_l = pi (l + 1/2) / n on [0, pi].
class AiryDiscAverage {
 public:
  // k = pi Rz / r [1/px], R > 0 the disc's radius [px]. The node count follows from 2 k R
  // with a margin that tests/airy_disc_average_test.cc confirms against a direct quadrature
  // over the disc. model::EnsureAiryTable(k (d + R)) must have been called for the largest d.
  AiryDiscAverage(double k, double radius);

  // S at distance d >= 0 [px], and (when the pointers are not null) dS/dk and dS/dR.
  void Evaluate(double d, double* value, double* d_dk, double* d_dR) const;

  int nodes() const { return static_cast<int>(cos_theta_.size()); }

 private:
  double k_, radius_;
  std::vector<double> cos_theta_;
};

}  // namespace ccdpsf::internal

#endif  // CCDPSF_INTERNAL_AIRY_DISC_AVERAGE_H_
