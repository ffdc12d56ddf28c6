#include "ccdpsf/fit/prior_report.h"

#include <cmath>
#include <cstdio>
#include <sstream>

namespace ccdpsf::fit {
namespace {

using nlohmann::json;

json Num(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

std::string Fmt(double v, int digits = 4) {
  if (!std::isfinite(v)) return "-";
  char text[64];
  std::snprintf(text, sizeof text, "%.*g", digits, v);
  return text;
}

// "boundary_shift.a_10" -> "a_10": the parameter's name within its effect.
std::string ShortName(const std::string& name) {
  const size_t dot = name.rfind('.');
  return dot == std::string::npos ? name : name.substr(dot + 1);
}

// One row of the comparison: the prior's (flats'), the data's alone (spots') and the
// posterior's values of parameter a (the prior's order).
struct Row {
  std::string name;
  double flat = NAN, flat_sd = NAN;
  double spot = NAN, spot_sd = NAN;
  double joint = NAN, joint_sd = NAN;
  double difference_sd = NAN;
};

Row MakeRow(const FitModel& model, const FitResult& result, int a) {
  const GaussianPriorTerm& term = model.gaussian_prior();
  const GaussianPrior& prior = term.prior();
  const int m = term.size(), index = term.indices()[a];
  Row row;
  row.name = ShortName(prior.names[a]);
  row.flat = prior.mean[a];
  row.flat_sd = std::sqrt(prior.covariance[static_cast<size_t>(a) * m + a]);
  if (index < static_cast<int>(result.parameters.size())) {
    row.joint = result.parameters[index].map;
    row.joint_sd = result.parameters[index].laplace_sd;
  }
  const DataAloneEstimate& d = result.data_alone;
  if (d.available) {
    row.spot = d.mean[a];
    row.spot_sd = d.sd[a];
    row.difference_sd =
        (row.spot - row.flat) / std::sqrt(row.spot_sd * row.spot_sd + row.flat_sd * row.flat_sd);
  }
  return row;
}

}  // namespace

json GaussianPriorJson(const FitModel& model) {
  const GaussianPriorTerm& term = model.gaussian_prior();
  if (!term.active()) return nullptr;
  const GaussianPrior& prior = term.prior();
  const int m = term.size();
  json sd = json::array(), covariance = json::array();
  for (int a = 0; a < m; ++a) {
    sd.push_back(std::sqrt(prior.covariance[static_cast<size_t>(a) * m + a]));
    json row = json::array();
    for (int b = 0; b < m; ++b) row.push_back(prior.covariance[static_cast<size_t>(a) * m + b]);
    covariance.push_back(row);
  }
  return {{"source", prior.source},
          {"parameters", prior.names},
          {"mean", prior.mean},
          {"sd", sd},
          {"covariance", covariance},
          {"truncated_to", "the flat ranges in priors"}};
}

json PriorComparisonJson(const FitModel& model, const FitResult& result) {
  const GaussianPriorTerm& term = model.gaussian_prior();
  if (!term.active()) return nullptr;
  json out = json::object();
  for (int a = 0; a < term.size(); ++a) {
    const Row row = MakeRow(model, result, a);
    json entry = {{"flat", {{"median", Num(row.flat)}, {"sd", Num(row.flat_sd)}}},
                  {"spots_and_flats", {{"map", Num(row.joint)}, {"laplace_sd", Num(row.joint_sd)}}},
                  {"difference_sd", Num(row.difference_sd)}};
    if (result.data_alone.available) {
      entry["spot"] = {{"median", Num(row.spot)}, {"sd", Num(row.spot_sd)}};
    } else {
      entry["spot"] = nullptr;
      entry["spot_unavailable_because"] = result.data_alone.why_not;
    }
    out[row.name] = entry;
  }
  return out;
}

std::string PriorComparisonMarkdown(const FitModel& model, const FitResult& result) {
  const GaussianPriorTerm& term = model.gaussian_prior();
  if (!term.active()) return "";
  std::ostringstream md;
  md << "## boundary_shift: spots against flats\n\n"
     << "Prior from " << term.prior().source
     << ": a Gaussian on a_10, a_01, a_11 with the flats' covariance, truncated to the flat "
        "ranges (a_far stays flat). \"Spots alone\" is what the spots say without it, from this "
        "fit's Laplace approximation (a_spot = a_post + S^-1 P (a_post - a_flat), "
        "docs/conventions.md), not a second fit.\n\n"
     << "| a_ij [1/e-] | flats | spots alone | spots + flats | (spots - flats) / sd |\n"
     << "|---|---|---|---|---|\n";
  for (int a = 0; a < term.size(); ++a) {
    const Row row = MakeRow(model, result, a);
    md << "| " << row.name << " | " << Fmt(row.flat) << " +- " << Fmt(row.flat_sd, 2) << " | "
       << (result.data_alone.available ? Fmt(row.spot) + " +- " + Fmt(row.spot_sd, 2)
                                       : std::string("-"))
       << " | " << Fmt(row.joint) << " +- " << Fmt(row.joint_sd, 2) << " | "
       << Fmt(row.difference_sd, 3) << " |\n";
  }
  md << "\n";
  if (!result.data_alone.available) {
    md << "No spots-alone values: " << result.data_alone.why_not << ".\n\n";
  }
  return md.str();
}

}  // namespace ccdpsf::fit
