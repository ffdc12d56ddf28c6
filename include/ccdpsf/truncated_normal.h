// Quantiles of a normal distribution truncated to an interval: the Laplace approximation of a
// posterior whose prior is flat on [lower, upper]. Intervals from it stay inside the prior's
// support (a Laplace "map +- 3 sd" can reach below zero for a coupling fraction that cannot).
#pragma once

namespace ccdpsf {

// Standard normal distribution function, accurate in both tails (erfc on the tail side).
double NormalCdf(double z);

// The q-quantile (0 < q < 1) of N(mean, sd^2) restricted to [lower, upper] (either may be
// infinite; lower < upper; sd > 0). Found by bisection on the distribution function, to a few
// ulp of the interval. Without bounds the quantile at NormalCdf(k) is mean + k sd exactly up
// to that precision.
double TruncatedNormalQuantile(double mean, double sd, double lower, double upper, double q);

}  // namespace ccdpsf
