// `ccdpsf grid` on full frames it did not make: spot grids photon-shot by the independent
// scripts tests/support/grid_frames.py (reference_sensor.py's physics; numpy and astropy, no
// ccdpsf code) with known, smoothly varying CCD widths, a crowded pair and an edge spot.
#include "ccdpsf/grid/grid.h"
#include "ccdpsf/grid/spot_relations.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "ccdpsf/trend/campaign.h"
#include "gtest/gtest.h"
#include "support/run_ccdpsf.h"

namespace ccdpsf {
namespace {

using testing_support::FreshDir;
using testing_support::RunAndKill;
using testing_support::RunCcdpsf;
using testing_support::RunResult;
using testing_support::Shell;

// Frames of a grid written by the independent script, made once per test run and shape: each
// case is its own process (ctest), and four cases share the small set, so the frames are kept
// in a folder named by the options and by the script's own text (a changed script makes new
// frames). A folder appears whole or not at all: it is written under a private name and
// renamed, and a case that loses the race to another uses the winner's (the script is
// deterministic in its options, so both are the same frames).
std::string GridFrames(const std::string& name, const std::string& options) {
  const std::string script = std::string(CCDPSF_SOURCE_DIR) + "/tests/support/grid_frames.py";
  std::ifstream in(script, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  const size_t key = std::hash<std::string>()(text.str() + "\n" + options);
  const std::string dir = ::testing::TempDir() + "/ccdpsf_grid_frames_" + name + "_" +
                          std::to_string(key);
  std::error_code ec;
  if (std::filesystem::exists(dir + "/truth.csv", ec)) return dir;
  const std::string own = FreshDir("grid_frames", name) + "/frames";
  std::string output;
  const int code = Shell("/usr/bin/python3 " + script + " " + own + " " + options, &output);
  EXPECT_EQ(code, 0) << output;
  std::filesystem::rename(own, dir, ec);  // fails if another case's frames are there first
  return std::filesystem::exists(dir + "/truth.csv", ec) ? dir : own;
}

std::string Frames(const std::string& dir, int n) {
  std::string files;
  for (int k = 0; k < n; ++k) {
    char name[32];
    std::snprintf(name, sizeof(name), "/frame_%03d.fits", k);
    files += " " + dir + name;
  }
  return files;
}

// A CSV file as rows of named cells (RFC 4180 quoting: the reason column holds commas).
using Row = std::map<std::string, std::string>;
std::vector<Row> ReadCsv(const std::string& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  const std::string s = text.str();
  std::vector<std::vector<std::string>> records(1, std::vector<std::string>(1));
  bool quoted = false;
  for (size_t i = 0; i < s.size(); ++i) {
    const char c = s[i];
    if (quoted) {
      if (c == '"' && i + 1 < s.size() && s[i + 1] == '"') {
        records.back().back() += '"';
        ++i;
      } else if (c == '"') {
        quoted = false;
      } else {
        records.back().back() += c;
      }
    } else if (c == '"') {
      quoted = true;
    } else if (c == ',') {
      records.back().emplace_back();
    } else if (c == '\n') {
      records.emplace_back(1);
    } else {
      records.back().back() += c;
    }
  }
  while (!records.empty() && records.back().size() == 1 && records.back()[0].empty()) {
    records.pop_back();
  }
  std::vector<Row> rows;
  for (size_t r = 1; r < records.size(); ++r) {
    EXPECT_EQ(records[r].size(), records[0].size()) << path << " record " << r;
    Row row;
    for (size_t c = 0; c < records[0].size() && c < records[r].size(); ++c) {
      row[records[0][c]] = records[r][c];
    }
    rows.push_back(std::move(row));
  }
  return rows;
}

double Number(const Row& row, const std::string& name) {
  const auto it = row.find(name);
  return it == row.end() || it->second.empty() ? NAN : std::stod(it->second);
}

// The truth row nearest `row` by position, and its distance [px]: grid spots are hundreds of
// pixels apart and a fitted centroid within 0.1 px of its truth.
const Row* NearestTruth(const std::vector<Row>& truth, const Row& row, double* distance) {
  const Row* best = nullptr;
  *distance = INFINITY;
  for (const Row& t : truth) {
    const double d =
        std::hypot(Number(t, "x_px") - Number(row, "x_px"), Number(t, "y_px") - Number(row, "y_px"));
    if (d < *distance) *distance = d, best = &t;
  }
  return best;
}

// Pulls of the identified widths against the truth, for every spot with verdict ok: the
// truth spot nearest each map row (grid spots are hundreds of pixels apart; the centroid is
// within 0.1 px of the truth). Returns the pulls, (fit - truth) / half the 68 % interval.
std::vector<double> Pulls(const std::vector<Row>& map, const std::vector<Row>& truth,
                          int* ok_spots) {
  std::vector<double> pulls;
  *ok_spots = 0;
  for (const Row& r : map) {
    if (r.at("verdict") != "ok") continue;
    ++*ok_spots;
    double best_d = INFINITY;
    const Row* best = NearestTruth(truth, r, &best_d);
    EXPECT_LT(best_d, 0.5) << "spot " << r.at("spot");
    EXPECT_EQ(best->at("kind"), "grid") << "spot " << r.at("spot");
    for (const char* m : {"total_sigma_x_px", "total_sigma_y_px", "total_fwhm_um"}) {
      const std::string name = m;
      const double half = 0.5 * (Number(r, name + "_hi68") - Number(r, name + "_lo68"));
      EXPECT_GT(half, 0.0) << name;
      pulls.push_back((Number(r, name) - Number(*best, name)) / half);
    }
  }
  return pulls;
}

// A 1024 x 1024 frame pair with a 3 x 3 grid: every grid spot fitted and holding the truth,
// the crowded pair and the edge spot refused with their reasons, valid FITS tables.
TEST(Grid, SmallGridHoldsTheTruthAndRefusesCrowdedAndEdgeSpots) {
  const std::string frames = GridFrames("small", "--size 1024 --grid 3 --exposures 2 --seed 5");
  const std::string out = FreshDir("Grid", "small") + "/out";
  const RunResult r = RunCcdpsf("grid --nomcmc --out=" + out + Frames(frames, 2));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("grid of 12 spots in 1 setting(s): 9 fitted (9 ok), 3 not fitted "
                          "(2 crowded, 1 edge)"),
            std::string::npos)
      << r.output;
  const std::vector<Row> map = ReadCsv(out + "/psf_map.csv");
  const std::vector<Row> truth = ReadCsv(frames + "/truth.csv");
  ASSERT_EQ(map.size(), 12u);
  int crowded = 0, edge = 0;
  for (const Row& row : map) {
    if (row.at("verdict") != "refused") continue;
    const std::string& reason = row.at("reason");
    crowded += reason.rfind("crowded: other light 4-7 px", 0) == 0;
    edge += reason.rfind("edge: its 21 x 21 stamp does not fit", 0) == 0;
    EXPECT_TRUE(std::isnan(Number(row, "total_fwhm_um"))) << "a refused spot has no numbers";
  }
  EXPECT_EQ(crowded, 2);
  EXPECT_EQ(edge, 1);
  int ok = 0;
  const std::vector<double> pulls = Pulls(map, truth, &ok);
  EXPECT_EQ(ok, 9);
  // 27 pulls of Laplace intervals on exact-model data: each Gaussian, P(|z| > 4) = 6e-5.
  for (double p : pulls) EXPECT_LT(std::fabs(p), 4.0);

  // The catalogue: every source of both frames, the fittable ones and the refused.
  const std::vector<Row> catalogue = ReadCsv(out + "/catalogue.csv");
  EXPECT_EQ(catalogue.size(), 24u);
  // Valid FITS for astropy, TOPCAT and DS9; the regions hold one circle per spot.
  for (const char* table : {"psf_map.fits", "catalogue.fits"}) {
    std::string said;
    EXPECT_EQ(Shell("fitsverify -q " + out + "/" + table, &said), 0) << said;
    EXPECT_NE(said.find("verification OK"), std::string::npos) << said;
  }
  std::ifstream reg(out + "/spots.reg");
  std::string line;
  int circles = 0;
  while (std::getline(reg, line)) circles += line.rfind("circle(", 0) == 0;
  EXPECT_EQ(circles, 12);
}

// The shards of a run merge to the run on one process, number for number: each process fits
// spots i % size == rank with spot i's seed, and the first puts the results together. Here
// the two "processes" run one after the other in this test, and the gather hands the first
// one the second's results; MCMC on, so that the seeds matter.
TEST(Grid, ShardsMergeToTheRunOnOneProcess) {
  const std::string frames = GridFrames("small", "--size 1024 --grid 3 --exposures 2 --seed 5");
  std::vector<trend::CampaignGroup> settings;
  std::string error;
  ASSERT_TRUE(trend::LoadCampaign({frames + "/frame_000.fits", frames + "/frame_001.fits"},
                                  &settings, &error))
      << error;
  ASSERT_EQ(settings.size(), 1u);
  grid::GridOptions options;
  options.fit.config.fit.mcmc.max_steps = 300;  // short chains: equality, not accuracy
  options.fit.config.fit.mcmc.target_ess = 50;
  options.fit.parallel_groups = 2;
  options.fit.draws = 50;
  grid::GridResult one;
  ASSERT_TRUE(grid::RunGrid(settings, options, &one, &error)) << error;

  std::string second_text;
  grid::GridResult second, first;
  options.size = 2;
  options.rank = 1;
  options.fit.parallel_groups = 1;  // and another thread count
  options.gather = [&](const std::string& text) {
    second_text = text;
    return std::vector<std::string>{};
  };
  ASSERT_TRUE(grid::RunGrid(settings, options, &second, &error)) << error;
  options.rank = 0;
  options.gather = [&](const std::string& text) {
    return std::vector<std::string>{text, second_text};
  };
  ASSERT_TRUE(grid::RunGrid(settings, options, &first, &error)) << error;

  ASSERT_EQ(first.spots.size(), one.spots.size());
  int fitted = 0;
  for (size_t i = 0; i < one.spots.size(); ++i) {
    const grid::SpotEntry& a = one.spots[i];
    const grid::SpotEntry& b = first.spots[i];
    EXPECT_EQ(a.spot, b.spot);
    EXPECT_EQ(a.where.x_px, b.where.x_px);
    EXPECT_EQ(a.where.refused, b.where.refused);
    ASSERT_EQ(a.fitted, b.fitted);
    if (!a.fitted) continue;
    ++fitted;
    EXPECT_TRUE(a.fit.ok) << a.fit.failure;
    EXPECT_EQ(a.fit.chi2_per_dof, b.fit.chi2_per_dof);
    ASSERT_EQ(a.fit.summaries.size(), b.fit.summaries.size());
    for (const auto& [name, s] : a.fit.summaries) {
      const fit::Summary& t = b.fit.summaries.at(name);
      // Bit for bit (NaN where both lack the number).
      for (auto [x, y] : {std::pair{s.map, t.map},
                          {s.median, t.median},
                          {s.lo68, t.lo68},
                          {s.hi68, t.hi68},
                          {s.laplace_sd, t.laplace_sd}}) {
        EXPECT_TRUE(x == y || (std::isnan(x) && std::isnan(y))) << name << " spot " << i;
      }
    }
  }
  EXPECT_EQ(fitted, 9);
  // The second shard alone holds only its own spots (odd indices).
  for (const grid::SpotEntry& e : second.spots) EXPECT_EQ(e.spot % 2, 1);
}

// Two MPI processes write the same psf_map as one process, byte for byte.
TEST(Grid, MpirunWithTwoProcessesWritesTheSameMap) {
  std::string said;
  if (Shell("command -v mpirun", &said) != 0) GTEST_SKIP() << "mpirun not installed";
  const std::string frames = GridFrames("small", "--size 1024 --grid 3 --exposures 2 --seed 5");
  const std::string dir = FreshDir("Grid", "mpirun");
  const std::string common = " --target_ess=100" + Frames(frames, 2);
  const RunResult one = RunCcdpsf("grid --out=" + dir + "/one --threads=2" + common);
  ASSERT_EQ(one.exit_code, 0) << one.output;
  // Root may run mpirun only when told so; the container's 2 cores are its 2 slots.
  const std::string mpirun =
      "OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 "
      "OMPI_MCA_rmaps_base_oversubscribe=1 mpirun -np 2 " CCDPSF_BINARY " grid --out=" +
      dir + "/two --threads=1" + common + " 2>&1";
  std::string output;
  ASSERT_EQ(Shell(mpirun, &output), 0) << output;
  EXPECT_NE(output.find("[process 1]"), std::string::npos) << output;
  for (const char* file : {"psf_map.fits", "psf_map.csv", "catalogue.csv"}) {
    std::string diff;
    EXPECT_EQ(Shell("cmp " + dir + "/one/" + file + " " + dir + "/two/" + file, &diff), 0)
        << file << ": " << diff;
  }
}

// The case: 4096 x 4096 frames, a 7 x 7 grid whose CCD widths vary across the
// sensor, three exposures: all 49 spots fitted, the map holds the truth within its intervals,
// the crowded pair and the edge spot refused.
TEST(Grid, FullSensorGridHoldsTheTruth) {
  const std::string frames = GridFrames("full", "--size 4096 --grid 7 --exposures 3 --seed 1");
  const std::string out = FreshDir("Grid", "full") + "/out";
  const RunResult r = RunCcdpsf("grid --nomcmc --out=" + out + Frames(frames, 3));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("49 fitted (49 ok), 3 not fitted (2 crowded, 1 edge)"), std::string::npos)
      << r.output;
  int ok = 0;
  const std::vector<double> pulls =
      Pulls(ReadCsv(out + "/psf_map.csv"), ReadCsv(frames + "/truth.csv"), &ok);
  EXPECT_EQ(ok, 49);
  ASSERT_EQ(pulls.size(), 147u);
  int inside = 0;
  for (double p : pulls) {
    inside += std::fabs(p) <= 1.0;
    EXPECT_LT(std::fabs(p), 4.5);  // 147 Gaussian pulls: P(any beyond 4.5) = 1e-3
  }
  // 68.3 % intervals: 100 of 147 expected inside; the three metrics of a spot are strongly
  // correlated (total FWHM is the geometric mean of the widths), so the count varies more
  // than a binomial's sd of 5.6: accept 3 binomial sds of the 98 independent width pulls,
  // scaled to 147, i.e. 100 +- 21.
  EXPECT_GE(inside, 79);
  EXPECT_LE(inside, 121);
}

// A through-focus frame set (five focus positions, defocus sigma 0.8, 0.4, 0, 0.4, 0.8 px):
// each spot is fitted with the through-focus model, which identifies its CCD widths; the map
// of ccd_sigma_x_px / ccd_sigma_y_px holds the truth that varies across the sensor.
TEST(Grid, ThroughFocusGridIdentifiesEachSpotsCcdWidths) {
  const std::string frames = GridFrames(
      "focus", "--size 1024 --grid 3 --flux_e 2e5 --focus_um=-100,-50,0,50,100 "
               "--defocus_px=0.8,0.4,0.0,0.4,0.8 --no_extras --seed 3");
  const std::string out = FreshDir("Grid", "focus") + "/out";
  const RunResult r = RunCcdpsf("grid --nomcmc --out=" + out + Frames(frames, 5));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const std::vector<Row> map = ReadCsv(out + "/psf_map.csv");
  const std::vector<Row> truth = ReadCsv(frames + "/truth.csv");
  ASSERT_EQ(map.size(), 9u);
  int ok = 0;
  for (const Row& row : map) {
    EXPECT_EQ(row.at("focus_series"), "1");
    if (row.at("verdict") != "ok") continue;
    ++ok;
    double best_d = INFINITY;
    const Row* best = NearestTruth(truth, row, &best_d);
    ASSERT_LT(best_d, 0.5);
    for (const char* m : {"ccd_sigma_x_px", "ccd_sigma_y_px"}) {
      const std::string name = m;
      const double half = 0.5 * (Number(row, name + "_hi68") - Number(row, name + "_lo68"));
      // 18 Gaussian pulls of Laplace intervals: P(any beyond 4) = 1e-3.
      EXPECT_LT(std::fabs(Number(row, name) - Number(*best, name)), 4.0 * half)
          << name << " spot " << row.at("spot");
      // Identified: an interval far narrower than the prior's 0.1-1 px.
      EXPECT_LT(half, 0.03) << name;
    }
  }
  EXPECT_EQ(ok, 9);
  EXPECT_TRUE(std::filesystem::exists(out + "/plots/map_ccd_sigma_x_px.dat") ||
              std::filesystem::exists(out + "/plots/map_ccd_sigma_x_px_spots.dat"));
}

// A campaign of three wavelengths, each a through-focus set (the CCD widths identified per
// spot), with diffusion widths sigma ~ lambda^alpha and alpha varying across the sensor: each
// spot's relation of the CCD FWHM (sqrt(sigma_x sigma_y)) with wavelength has alpha =
// (alpha_x + alpha_y) / 2, the truth's exponents (grid_frames.py's law).
TEST(Grid, EachSpotsAlphaAcrossWavelengthsHoldsTheTruth) {
  std::string files;
  std::string truth_dir;
  for (const char* wavelength : {"650", "750", "850"}) {
    const std::string dir = GridFrames(
        std::string("focus_") + wavelength,
        std::string("--size 1024 --grid 3 --flux_e 2e5 --focus_um=-100,-50,0,50,100 "
                    "--defocus_px=0.8,0.4,0.0,0.4,0.8 --no_extras --seed 3 --wavelength_nm ") +
            wavelength);
    files += Frames(dir, 5);
    if (truth_dir.empty()) truth_dir = dir;
  }
  const std::string out = FreshDir("Grid", "alpha") + "/out";
  const RunResult r = RunCcdpsf("grid --nomcmc --out=" + out + files);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("grid of 27 spots in 3 setting(s): 27 fitted (27 ok)"),
            std::string::npos)
      << r.output;
  const std::vector<Row> relations = ReadCsv(out + "/spot_relations.csv");
  const std::vector<Row> truth = ReadCsv(truth_dir + "/truth.csv");
  int checked = 0;
  for (const Row& rel : relations) {
    if (rel.at("relation") != "fwhm_um_vs_wavelength") continue;
    EXPECT_EQ(rel.at("n_points"), "3");
    double best_d = INFINITY;
    const Row* best = NearestTruth(truth, rel, &best_d);
    ASSERT_LT(best_d, 0.5);
    const double expected = 0.5 * (Number(*best, "alpha_x") + Number(*best, "alpha_y"));
    const double half = 0.5 * (Number(rel, "alpha_hi68") - Number(rel, "alpha_lo68"));
    // 9 pulls from Gaussian (Laplace) points: P(any beyond 4) = 6e-4.
    EXPECT_LT(std::fabs(Number(rel, "alpha") - expected), 4.0 * half)
        << "track " << rel.at("track") << ": alpha " << rel.at("alpha") << ", truth "
        << expected;
    EXPECT_LT(half, 0.05);  // ~1 % widths over 650-850 nm: alpha to a few hundredths
    ++checked;
  }
  EXPECT_EQ(checked, 9);
}

// A killed grid keeps the spots it had finished: --resume fits only the others and writes
// the same map as an uninterrupted run.
TEST(Grid, AKilledGridResumesWithItsFinishedSpots) {
  const std::string frames = GridFrames("small", "--size 1024 --grid 3 --exposures 2 --seed 5");
  const std::string dir = FreshDir("Grid", "resume");
  const std::string options = " --threads=1 --target_ess=100" + Frames(frames, 2);
  ASSERT_EQ(RunCcdpsf("grid --out=" + dir + "/whole" + options).exit_code, 0);
  const std::string store = dir + "/.killed.ccdpsf-partial/store";
  auto finished = [&] {
    int n = 0;
    std::error_code ec;
    for (const auto& e : std::filesystem::directory_iterator(store, ec)) {
      n += e.path().extension() == ".json";
    }
    return n >= 3;
  };
  ASSERT_TRUE(RunAndKill("grid --out=" + dir + "/killed" + options, finished));
  const RunResult r = RunCcdpsf("grid --resume --out=" + dir + "/killed" + options);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  int kept = 0;
  for (size_t at = 0; (at = r.output.find("kept from an earlier run", at)) != std::string::npos;
       ++at) {
    ++kept;
  }
  EXPECT_GE(kept, 3) << r.output;
  EXPECT_LT(kept, 9) << r.output;
  std::string diff;
  EXPECT_EQ(Shell("cmp " + dir + "/whole/psf_map.fits " + dir + "/killed/psf_map.fits", &diff), 0)
      << diff;
  EXPECT_FALSE(std::filesystem::exists(dir + "/killed/store"));
}

// Serial CTI that grows across the sensor, added to the grid's frames by the independent
// script tests/support/add_serial_cti.py: f(x) = C (x + 1) for the x + 1 transfers of column x
// to the output, C = 1e-5 (f from 1.7e-3 at the left column of spots to 8.5e-3 at the right:
// the unirradiated to end-of-life range of the catalogue), trail length 1.5 px. Each spot's
// fit with --effects=serial_cti recovers its own f(x_c) and the length, and with the trail
// in the model the identified widths still hold the CTI-free truth. Tolerances: Laplace
// intervals of a model that holds the data (the script's f varies by +-2 C = 2e-5 over the
// light of a spot against an sd of ~3e-4): Gaussian pulls, |z| < 4 for 9 spots (P = 6e-4).
TEST(Grid, SerialCtiAcrossTheSensorIsRecoveredPerSpot) {
  const std::string frames =
      GridFrames("cti", "--size 1024 --grid 3 --exposures 2 --seed 7 --no_extras");
  const std::string dir = FreshDir("Grid", "cti");
  std::string said;
  ASSERT_EQ(Shell("/usr/bin/python3 " + std::string(CCDPSF_SOURCE_DIR) +
                      "/tests/support/add_serial_cti.py " + frames + " " + dir +
                      "/frames --per_transfer 1e-5 --trail_length_px 1.5",
                  &said),
            0)
      << said;
  const std::string out = dir + "/out";
  const RunResult r =
      RunCcdpsf("grid --nomcmc --effects=serial_cti --out=" + out + Frames(dir + "/frames", 2));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const std::vector<Row> map = ReadCsv(out + "/psf_map.csv");
  const std::vector<Row> truth = ReadCsv(frames + "/truth.csv");
  ASSERT_EQ(map.size(), 9u);
  double f_min = INFINITY, f_max = 0.0;
  for (const Row& row : map) {
    SCOPED_TRACE("spot " + row.at("spot"));
    ASSERT_NE(row.at("verdict"), "refused");
    double d = INFINITY;
    const Row* t = NearestTruth(truth, row, &d);
    ASSERT_LT(d, 0.5);
    const double f_true = 1e-5 * (Number(*t, "x_px") + 1.0);
    f_min = std::min(f_min, f_true);
    f_max = std::max(f_max, f_true);
    for (const auto& [name, want] : std::vector<std::pair<std::string, double>>{
             {"serial_cti_trail_fraction", f_true}, {"serial_cti_trail_length_px", 1.5}}) {
      const double half = 0.5 * (Number(row, name + "_hi68") - Number(row, name + "_lo68"));
      ASSERT_GT(half, 0.0) << name;
      EXPECT_LT(std::fabs(Number(row, name) - want) / half, 4.0)
          << name << " " << Number(row, name) << " against " << want;
    }
    // The trail is detected in every spot: f's interval is far from 0.
    EXPECT_GT(Number(row, "serial_cti_trail_fraction_lo68"), 0.5 * f_true);
  }
  EXPECT_GT(f_max, 4.0 * f_min);  // the map spans the range, not one value
  int ok = 0;
  for (double p : Pulls(map, truth, &ok)) EXPECT_LT(std::fabs(p), 4.0);
  EXPECT_GE(ok, 7);
  // The parameters' maps, and a valid table.
  for (const char* plot : {"map_serial_cti_trail_fraction", "map_serial_cti_trail_length_px"}) {
    EXPECT_TRUE(std::filesystem::exists(out + "/plots/" + plot + ".png")) << plot;
  }
  EXPECT_EQ(Shell("fitsverify -q " + out + "/psf_map.fits", &said), 0) << said;
  EXPECT_NE(said.find("verification OK"), std::string::npos) << said;
}

TEST(Grid, BadInputIsAOneLineError) {
  const std::string dir = FreshDir("Grid", "bad");
  RunResult r = RunCcdpsf("grid " + dir);
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("grid needs --out=DIR"), std::string::npos) << r.output;
  r = RunCcdpsf("grid --out=" + dir + "/o --spot_x_px=3 x.fits");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  std::ofstream(dir + "/not.fits") << "this is not FITS";
  r = RunCcdpsf("grid --out=" + dir + "/o --wavelength_nm=800 --gain_e_per_adu=1 " + dir +
                "/not.fits");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("not.fits"), std::string::npos) << r.output;
  EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
  // A spot is fitted over one setting, at one intensity: no brighter-fatter slope there.
  r = RunCcdpsf("grid --effects=brighter_fatter --out=" + dir + "/o " + dir + "/not.fits");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("grid cannot fit brighter_fatter"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(dir + "/o"));
}

}  // namespace
}  // namespace ccdpsf

namespace ccdpsf {
namespace {

// Relations per spot on a hand-made campaign: three settings at 600, 700 and 850 nm, two
// spots whose identified FWHM follows a lambda^alpha with a known alpha each (-0.3 and
// +0.2), posterior draws Gaussian with a 1 % sd; a third spot refused at 700 nm. Each
// spot's alpha is recovered within its interval (68 %: a 3-sigma window of its sd for the
// two spots), and the refused setting is a gap with the refusal as reason. The 850 nm fits
// are marked as identifying only total widths: the CCD-only fwhm_um relations have a gap
// there with that reason.
TEST(GridRelations, EachSpotsAlphaIsRecoveredAndRefusalsAreGaps) {
  grid::GridResult r;
  const std::vector<double> wavelengths = {600.0, 700.0, 850.0};
  const double xs[3] = {100.0, 900.0, 1700.0};
  const double alphas[3] = {-0.3, 0.2, 0.0};
  std::mt19937_64 rng(11);
  std::normal_distribution<double> unit(0.0, 1.0);
  int spot = 0;
  for (int s = 0; s < 3; ++s) {
    trend::CampaignGroup g;
    g.name = "w" + std::to_string(static_cast<int>(wavelengths[s]));
    g.wavelength_nm = wavelengths[s];
    r.settings.push_back(g);
    r.frames.emplace_back();
    for (int k = 0; k < 3; ++k) {
      grid::SpotEntry e;
      e.setting = s;
      e.spot = spot++;
      // Positions move by a few hundredths of a pixel between settings.
      e.where.x_px = xs[k] + 0.02 * s;
      e.where.y_px = 500.0 - 0.01 * s;
      e.fitted = !(k == 2 && s == 1);
      if (!e.fitted) {
        e.where.refused = "crowded";
        e.where.reason = "other light 4-7 px from its peak";
      } else {
        e.fit.ok = true;
        e.fit.peak_e.median = 1.5e5;
        const double truth = 9.0 * std::pow(wavelengths[s] / 800.0, alphas[k]);
        std::vector<double>& d = e.fit.draws["total_fwhm_um"];
        for (int i = 0; i < 400; ++i) d.push_back(truth * (1.0 + 0.01 * unit(rng)));
        e.fit.draws["fwhm_um"] = d;
        // At 850 nm the fits identify only total widths: fwhm_um is a gap there.
        e.fit.ccd_split_unidentified = s == 2;
      }
      r.spots.push_back(e);
    }
  }
  trend::RelationOptions options;
  const std::vector<grid::SpotRelation> relations = grid::FitSpotRelations(r, 3.0, options);
  int checked = 0;
  for (const grid::SpotRelation& rel : relations) {
    if (rel.metric != "fwhm_um") continue;
    bool gap_850 = false;
    for (const trend::RelationGap& g : rel.fit.gaps) {
      gap_850 = gap_850 || (g.abscissa == 850.0 &&
                            g.reason.find("CCD widths not identified") != std::string::npos);
    }
    EXPECT_TRUE(gap_850) << "track at x " << rel.x_px;
  }
  for (const grid::SpotRelation& rel : relations) {
    if (rel.metric != "total_fwhm_um") continue;
    ASSERT_EQ(rel.kind, trend::RelationKind::kPowerLaw);  // one setting per wavelength
    const int k = static_cast<int>(std::lround((rel.x_px - 100.0) / 800.0));
    ASSERT_GE(k, 0);
    ASSERT_LT(k, 3);
    EXPECT_EQ(rel.spots.size(), 3u);
    const trend::Coefficient* alpha = rel.fit.Find("alpha");
    ASSERT_NE(alpha, nullptr);
    if (k < 2) {
      EXPECT_TRUE(rel.fit.fitted);
      EXPECT_EQ(rel.fit.points.size(), 3u);
      EXPECT_LT(std::fabs(alpha->estimate.median - alphas[k]), 3.0 * alpha->estimate.sd)
          << "spot track " << k;
      // 1 % per point over ln(850/600) = 0.35: sd(alpha) ~ 0.03.
      EXPECT_LT(alpha->estimate.sd, 0.05);
    } else {
      ASSERT_EQ(rel.fit.gaps.size(), 1u);
      EXPECT_NE(rel.fit.gaps[0].reason.find("crowded"), std::string::npos);
      EXPECT_EQ(rel.fit.points.size(), 2u);
    }
    ++checked;
  }
  EXPECT_EQ(checked, 3);
}

}  // namespace
}  // namespace ccdpsf
