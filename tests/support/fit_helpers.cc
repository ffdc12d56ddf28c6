#include "support/fit_helpers.h"

#include "gtest/gtest.h"

namespace ccdpsf::testing_support {

std::unique_ptr<fit::FitModel> MustCreate(std::vector<Stamp> stamps,
                                          const fit::FitModelOptions& options) {
  std::string error;
  auto model = fit::FitModel::Create(std::move(stamps), options, &error);
  EXPECT_NE(model, nullptr) << error;
  return model;
}

fit::FitOptions NoMcmc() {
  fit::FitOptions o;
  o.run_mcmc = false;
  return o;
}

int DerivedIndex(const fit::FitResult& result, const std::string& name) {
  for (size_t i = 0; i < result.derived.size(); ++i) {
    if (result.derived[i].first == name) return static_cast<int>(i);
  }
  return -1;
}

}  // namespace ccdpsf::testing_support
