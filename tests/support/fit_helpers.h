// Small helpers shared by the fit-engine tests.
#ifndef CCDPSF_TESTS_SUPPORT_FIT_HELPERS_H_
#define CCDPSF_TESTS_SUPPORT_FIT_HELPERS_H_

#include <memory>
#include <string>
#include <vector>

#include "ccdpsf/fit/fit.h"
#include "ccdpsf/fit/fit_model.h"

namespace ccdpsf::testing_support {

// FitModel::Create, failing the current test (with the reason) when it returns nullptr.
std::unique_ptr<fit::FitModel> MustCreate(
    std::vector<Stamp> stamps, const fit::FitModelOptions& options = fit::FitModelOptions());

// Fit options with the MCMC switched off (MAP and Laplace only).
fit::FitOptions NoMcmc();

// Index of derived quantity `name` in FitResult::derived, -1 if absent.
int DerivedIndex(const fit::FitResult& result, const std::string& name);

}  // namespace ccdpsf::testing_support

#endif  // CCDPSF_TESTS_SUPPORT_FIT_HELPERS_H_
