// What `ccdpsf diagnose` leaves in its output folder (docs/formats.md, diagnose):
//   diagnose.json         named_effects (catalogue names in the order found, [] when nothing
//                         is missing), rounds (per round: the model and its effects, the fit's
//                         chi2/dof with its expected scatter, the statistics with predictive
//                         p-values, the candidate table with the evidence, the named effect or
//                         null, a one-line verdict), final_fit (every parameter's MAP and
//                         Laplace sd; the named effects' parameters with 68 % and 99.7 %
//                         Laplace intervals), detection_thresholds (computed: the simulated
//                         studies of --thresholds, per strength as injected the detection rate
//                         and the simulations whose fits failed, left out of it; not_named: for
//                         every effect not named, its realistic strength, its status and reason in
//                         the last round tested, and the weakest strength that would have been
//                         detected, simulated for these data or else the reference value for
//                         paper-like data, ReferenceThresholds in diagnose.h), notes. Written last.
//   report.md             a readable summary
//   stacked_residuals.*   stacked data / model / residual / normalised residual, one row per
//                         round (the gap before and after each named effect)
//   radial_profile.*      the stacked normalised residual's radial profile, per round
//   flag_<effect>.*       the statistic that flagged the effect (smallest predictive p-value in
//                         that round): its predictive distribution before and after, and the
//                         observed values
//   run.json              resolved options, seed, software versions
// All staged (staged_output.h): a failed run leaves nothing that looks complete.
#ifndef CCDPSF_DIAGNOSE_DIAGNOSE_REPORT_H_
#define CCDPSF_DIAGNOSE_DIAGNOSE_REPORT_H_

#include <string>
#include <vector>

#include "ccdpsf/diagnose/diagnose.h"
#include "ccdpsf/plot.h"
#include "nlohmann/json.hpp"

namespace ccdpsf::diagnose {

nlohmann::json DiagnoseJson(const fit::FitModel& base, const DiagnoseResult& result,
                            const DiagnoseOptions& options);

// Plot failures (no gnuplot) are warnings, not errors.
bool WriteDiagnoseReport(const std::string& out_dir, const fit::FitModel& base,
                         const DiagnoseResult& result, const DiagnoseOptions& options,
                         const nlohmann::json& run_record, std::vector<std::string>* warnings,
                         std::string* error, const PlotOptions& plot = PlotOptions());

}  // namespace ccdpsf::diagnose

#endif  // CCDPSF_DIAGNOSE_DIAGNOSE_REPORT_H_
