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

// The tables a disc average reads (model/airy.h: the encircled-energy ratio for S, the
// amplitude for the derivatives), ready up to v = k rho = v_max.
void EnsureDiscAverageTables(double v_max);

// The angular rule for one (k, R): midpoints theta_l = pi (l + 1/2) / n on [0, pi].
class AiryDiscAverage {
 public:
  // k = pi Rz / r [1/px], R > 0 the disc's radius [px]. The node count follows from 2 k R
  // with a margin that tests/unit/airy_disc_average_test.cc confirms against a direct quadrature
  // over the disc. EnsureDiscAverageTables(k (d + R)) must have been called for the largest d.
  AiryDiscAverage(double k, double radius);

  // S at distance d >= 0 [px], and (when the pointers are not null) dS/dk and dS/dR.
  void Evaluate(double d, double* value, double* d_dk, double* d_dR) const;
  // The same at four distances d[0..4) at once (the vector unit's width), into value[0..4)
  // and, when d_dk is not null, d_dk[0..4) and d_dR[0..4).
  void Evaluate4(const double* d, double* value, double* d_dk, double* d_dR) const;

  int nodes() const { return static_cast<int>(cos_theta_.size()); }

 private:
  double k_, radius_;
  std::vector<double> cos_theta_;
};

// S(d) and its derivatives on [0, d_max] as piecewise polynomials, for filling many nodes:
// S is band-limited to angular frequency 2 k (its transform is the pupil OTF times the
// disc's), so on a piece of half-length H the Chebyshev coefficients fall like J_m(2 k H):
// at 2 k H = 16, J_40(16) = 3e-13 of the peak, below the ~1e-12 of the Airy table the samples
// come from. Building takes kTerms AiryDiscAverage evaluations per piece (at its Chebyshev
// points). Each piece is then split into kSub sub-pieces, where the coefficients fall like
// J_l(16 / kSub) = J_l(4), J_20(4) = 4e-13, and each sub-piece's interpolant is stored as a
// power series in its local variable (airy_disc_average.cc says how, keeping the rounding at
// ~1e-14 of the peak). A node then costs kMonomials multiply-adds of Horner's rule (a Clenshaw
// sum over the whole piece cost twice the operations per term and twice the terms). (44 and
// 24 terms, at 5e-16 and 2e-17, measured the same against the circle integral and the direct
// quadrature, whose own errors dominate; they cost 12 % more per render.)
class AiryDiscProfile {
 public:
  static constexpr int kTerms = 40;      // a multiple of 4 (Build evaluates four points at once)
  static constexpr int kSub = 4;         // sub-pieces per piece
  static constexpr int kMonomials = 20;  // power-series terms per sub-piece

  // Same k and radius as AiryDiscAverage; derivs: also dS/dk (times dk_scale: the renderer
  // passes dk/dr to get the derivative by the Airy radius) and dS/dR. Reuses its storage.
  // EnsureDiscAverageTables(k (Reach(k, d_max) + radius)) must have been called.
  void Build(double k, double radius, double d_max, bool derivs, double dk_scale = 1.0);
  // The largest distance [px] Build evaluates S at: the end of the last piece.
  static double Reach(double k, double d_max);

  // S at d[0..n) (each in [0, d_max]) into value[], and when derivs, dS/dk (times dk_scale)
  // and dS/dR.
  void Evaluate(const double* d, int n, double* value, double* d_dk, double* d_dR) const;
  // The same at several runs of points: run r is d[at .. at + count), written to the outputs
  // at the same places. One call for a whole quadrant keeps the vector sums in full groups (a
  // quadrant column alone leaves a short remainder, whose sums run one at a time at a quarter
  // of the rate).
  struct Run {
    int at;
    int count;
  };
  void Evaluate(const double* d, const Run* runs, int num_runs, double* value, double* d_dk,
                double* d_dR) const;

  int pieces() const { return pieces_; }

 private:
  int pieces_ = 0;
  double half_length_ = 0.0;  // H [px]
  bool derivs_ = false;
  // Power-series coefficients a_i of sub-piece p (over all pieces, p = piece * kSub + s) and
  // quantity q (value, d/dk, d/dR) at [(p * 3 + q) * kMonomials + i].
  std::vector<double> coefficients_;
  std::vector<double> scratch_;

 public:
  // One vector sum of Evaluate: up to four consecutive points' local variable on one
  // sub-piece, which of the four lanes are used (-1: used, 0: not; the store mask's sign
  // bits), the sub-piece's coefficients, the first point's index.
  struct alignas(32) SumItem {
    double t[4];
    double use[4];
    const double* c;
    int at;
  };

 private:
  mutable std::vector<SumItem> items_;  // Evaluate's scratch space, not state
};

}  // namespace ccdpsf::internal

#endif  // CCDPSF_INTERNAL_AIRY_DISC_AVERAGE_H_
