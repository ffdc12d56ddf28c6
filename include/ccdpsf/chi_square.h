// Tail probabilities of the chi^2 distribution, accurate far into both tails (the regularized
// incomplete gamma functions: the series for P when x < a + 1, else the continued fraction
// for Q, both to ~1e-15 relative, each computed directly rather than as 1 minus the other).
#ifndef CCDPSF_CHI_SQUARE_H_
#define CCDPSF_CHI_SQUARE_H_

namespace ccdpsf {

// P(X >= chi2) for X ~ chi^2(dof): the p-value of a fit's chi^2. NaN for dof < 1 or a
// negative / non-finite chi2.
double ChiSquareUpperTail(double chi2, double dof);
// P(X <= chi2): small when a chi^2 is too small for its dof (noise overstated).
double ChiSquareLowerTail(double chi2, double dof);

}  // namespace ccdpsf

#endif  // CCDPSF_CHI_SQUARE_H_
