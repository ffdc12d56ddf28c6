// Path safety (issue 42): every path the tool writes or removes lies inside --out, names
// from files and manifests never climb out of it, the partial folder is never a link that
// is followed, and a read-only or foreign --out is refused and left as it was. Each case of
// the review is a test here; the expected names are written out by hand.
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "ccdpsf/output_folder.h"
#include "ccdpsf/safe_path.h"
#include "ccdpsf/trend/group_fit.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "support/run_ccdpsf.h"

namespace ccdpsf {
namespace {

namespace fs = std::filesystem;
using testing_support::DemoSet;
using testing_support::FreshDir;
using testing_support::RunCcdpsf;
using testing_support::RunResult;
using testing_support::Touch;
using testing_support::WriteRunRecord;

std::string Slurp(const std::string& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

// The entries of `dir`, sorted, for "nothing else changed" checks.
std::vector<std::string> Entries(const std::string& dir) {
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) names.push_back(e.path().filename().string());
  std::sort(names.begin(), names.end());
  return names;
}

TEST(PathSafety, SafeComponentNeverClimbsHidesOrSplits) {
  EXPECT_EQ(SafeComponent("exposure_000"), "exposure_000");
  EXPECT_EQ(SafeComponent(".."), "_..");  // the stem of "...fits"
  EXPECT_EQ(SafeComponent("."), "_.");
  EXPECT_EQ(SafeComponent(""), "_");
  EXPECT_EQ(SafeComponent("../../victim"), "_.._.._victim");
  EXPECT_EQ(SafeComponent("a/b\\c"), "a_b_c");
  EXPECT_EQ(SafeComponent(".hidden"), "_.hidden");
  EXPECT_EQ(SafeComponent("800 nm\n"), "800_nm_");
  EXPECT_EQ(SafeComponent("g1,800nm=+2@x"), "g1,800nm=+2@x");
  EXPECT_EQ(SafeComponent(std::string(300, 'a')), std::string(120, 'a'));
}

TEST(PathSafety, UniqueSafeComponentsNumberClashesInOrder) {
  EXPECT_EQ(UniqueSafeComponents({"a", "b"}), (std::vector<std::string>{"a", "b"}));
  // Equal after sanitising, equal but for case (a case-insensitive disk), equal outright.
  EXPECT_EQ(UniqueSafeComponents({"x/y", "x_y", "X_Y", "x_y"}),
            (std::vector<std::string>{"x_y", "x_y_2", "X_Y_3", "x_y_4"}));
  EXPECT_EQ(UniqueSafeComponents({"..", "_.."}), (std::vector<std::string>{"_..", "_.._2"}));
}

TEST(PathSafety, IsInsideFolderRefusesParentsItselfAndLinks) {
  const std::string root = FreshDir("PathSafety", "inside");
  fs::create_directories(root + "/out/real");
  fs::create_directories(root + "/elsewhere");
  fs::create_directory_symlink(root + "/elsewhere", root + "/out/link");
  std::string error;
  EXPECT_TRUE(IsInsideFolder(root + "/out", root + "/out/real/file", &error)) << error;
  EXPECT_TRUE(IsInsideFolder(root + "/out", root + "/out/not_yet/deeper", &error)) << error;
  // The link itself may be removed (that removes the link, not its target)...
  EXPECT_TRUE(IsInsideFolder(root + "/out", root + "/out/link", &error)) << error;
  // ...but nothing is reached through it.
  EXPECT_FALSE(IsInsideFolder(root + "/out", root + "/out/link/file", &error));
  EXPECT_NE(error.find("symbolic link"), std::string::npos) << error;
  EXPECT_FALSE(IsInsideFolder(root + "/out", root + "/out/../elsewhere", &error));
  EXPECT_FALSE(IsInsideFolder(root + "/out", root + "/out/real/../../x", &error));
  EXPECT_FALSE(IsInsideFolder(root + "/out", root + "/out", &error));
  EXPECT_FALSE(IsInsideFolder(root + "/out", root + "/out/.", &error));
}

// Issue 42, case 1 (library level): a group named after a manifest setting of
// "../../victim", and one named ".." (the stem of a failing "...fits"), are fitted with
// their reports under reports_dir; neither the victim beside --out nor reports_dir itself
// is removed.
TEST(PathSafety, GroupNamesNeverRemoveAnythingOutsideTheReportsFolder) {
  const std::string root = FreshDir("PathSafety", "groups");
  const std::string reports = root + "/.out.ccdpsf-partial/groups";
  fs::create_directories(reports);
  Touch(reports + "/../kept.txt");  // another group's file in the partial folder
  fs::create_directories(root + "/victim");
  Touch(root + "/victim/precious.txt", "mine");
  std::vector<trend::CampaignGroup> groups(2);
  groups[0].name = "../../victim";
  groups[1].name = "..";
  for (trend::CampaignGroup& g : groups) g.problem = "cannot be fitted (test)";
  trend::GroupFitOptions options;
  options.reports_dir = reports;
  const std::vector<trend::GroupResult> results = trend::FitGroups(groups, options, nullptr);
  ASSERT_EQ(results.size(), 2u);
  EXPECT_FALSE(results[0].ok);
  EXPECT_EQ(Slurp(root + "/victim/precious.txt"), "mine");
  EXPECT_TRUE(fs::is_directory(reports));
  EXPECT_TRUE(fs::exists(reports + "/../kept.txt"));
}

// Issue 42, case 1 (end to end): trend with a manifest whose setting is "../../victim".
TEST(PathSafety, TrendManifestSettingCannotReachOutsideOut) {
  const std::string root = FreshDir("PathSafety", "trend");
  fs::create_directories(root + "/victim");
  Touch(root + "/victim/precious.txt", "mine");
  fs::create_directories(root + "/data");
  fs::copy_file(DemoSet() + "/exposure_000.fits", root + "/data/a.fits");
  const nlohmann::json manifest = {
      {"exposures", {{{"file", "a.fits"}, {"setting", "../../victim"}}}}};
  Touch(root + "/data/manifest.json", manifest.dump());
  const RunResult r = RunCcdpsf("trend --nomcmc --plot_format=svg --group_plots=none --out=" +
                                root + "/out --manifest=" + root + "/data/manifest.json");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(Slurp(root + "/victim/precious.txt"), "mine");
  EXPECT_EQ(Entries(root + "/victim"), std::vector<std::string>{"precious.txt"});
  EXPECT_EQ(Entries(root), (std::vector<std::string>{"data", "out", "victim"}));
  EXPECT_TRUE(fs::exists(root + "/out/groups/_.._.._victim/fit.json")) << r.output;
}

// Issue 42, case 2: a file named "...fits" (stem "..") in a fit of several files writes its
// results inside --out, not into --out's parent over the user's report.md.
TEST(PathSafety, AFileNamedDotDotDotFitsStaysInsideOut) {
  const std::string root = FreshDir("PathSafety", "dots");
  Touch(root + "/report.md", "the user's own report");
  fs::create_directories(root + "/data");
  fs::copy_file(DemoSet() + "/exposure_000.fits", root + "/data/...fits");
  fs::copy_file(DemoSet() + "/exposure_001.fits", root + "/data/b.fits");
  const RunResult r = RunCcdpsf("fit --nomcmc --plots=none --out=" + root + "/out " + root +
                                "/data/...fits " + root + "/data/b.fits");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(Slurp(root + "/report.md"), "the user's own report");
  EXPECT_EQ(Entries(root), (std::vector<std::string>{"data", "out", "report.md"}));
  EXPECT_TRUE(fs::exists(root + "/out/_../fit.json"));
  EXPECT_TRUE(fs::exists(root + "/out/b/fit.json"));
}

// Issue 42, case 3: a symbolic link planted at the predictable partial folder's name is not
// followed: the run is refused, the link's target keeps its files, the link stays a link.
TEST(PathSafety, ALinkPlantedAtThePartialFolderIsNotFollowed) {
  const std::string root = FreshDir("PathSafety", "planted");
  fs::create_directories(root + "/target");
  Touch(root + "/target/keep.txt", "keep");
  fs::create_directory_symlink(root + "/target", root + "/.out.ccdpsf-partial");
  {
    OutputFolder folder;
    std::string error;
    EXPECT_FALSE(folder.Begin(root + "/out", {}, {}, &error));
    EXPECT_NE(error.find("symbolic link"), std::string::npos) << error;
    EXPECT_EQ(error.find('\n'), std::string::npos);
  }
  EXPECT_EQ(Slurp(root + "/target/keep.txt"), "keep");
  EXPECT_TRUE(fs::is_symlink(root + "/.out.ccdpsf-partial"));
  EXPECT_FALSE(fs::exists(root + "/out"));
  // Also through the binary, which exits 1 with the one line.
  const RunResult r = RunCcdpsf("fit --nomcmc --out=" + root + "/out " + DemoSet() +
                                "/exposure_000.fits");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("symbolic link"), std::string::npos) << r.output;
  EXPECT_EQ(Slurp(root + "/target/keep.txt"), "keep");
}

// The partial folder a run creates is private (mode 0700): nobody else can plant files in
// it while the run writes.
TEST(PathSafety, ThePartialFolderIsCreatedPrivate) {
  const std::string root = FreshDir("PathSafety", "private");
  OutputFolder folder;
  std::string error;
  ASSERT_TRUE(folder.Begin(root + "/out", {}, {}, &error)) << error;
  struct stat st;
  ASSERT_EQ(::lstat(folder.partial().c_str(), &st), 0);
  EXPECT_TRUE(S_ISDIR(st.st_mode));
  EXPECT_EQ(st.st_mode & 0777, 0700u);
}

// Issue 42, case 4: an earlier result folder the user made read-only is refused and left
// whole (no files stranded in a hidden partial folder, later runs unaffected).
TEST(PathSafety, AReadOnlyOutIsRefusedAndLeftAsItWas) {
  const std::string root = FreshDir("PathSafety", "readonly");
  const std::string out = root + "/out";
  fs::create_directories(out);
  WriteRunRecord(out);
  Touch(out + "/fit.json", "earlier");
  ASSERT_EQ(::chmod(out.c_str(), 0555), 0);
  const RunResult r =
      RunCcdpsf("fit --nomcmc --out=" + out + " " + DemoSet() + "/exposure_000.fits");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("read-only (mode 555)"), std::string::npos) << r.output;
  EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
  EXPECT_EQ(Slurp(out + "/fit.json"), "earlier");
  EXPECT_EQ(Entries(root), std::vector<std::string>{"out"});  // no partial folder left
  // A read-only folder inside an earlier output is refused alike.
  ASSERT_EQ(::chmod(out.c_str(), 0755), 0);
  fs::create_directories(out + "/sub");
  ASSERT_EQ(::chmod((out + "/sub").c_str(), 0555), 0);
  OutputFolder folder;
  std::string error;
  EXPECT_FALSE(folder.Begin(out, {}, {}, &error));
  EXPECT_NE(error.find("sub"), std::string::npos) << error;
  ASSERT_EQ(::chmod((out + "/sub").c_str(), 0755), 0);
}

// Issue 42, case 4: an --out that is a symbolic link is refused; it stays a link and its
// target keeps its files.
TEST(PathSafety, AnOutThatIsALinkIsRefused) {
  const std::string root = FreshDir("PathSafety", "outlink");
  fs::create_directories(root + "/real");
  WriteRunRecord(root + "/real");
  fs::create_directory_symlink(root + "/real", root + "/out");
  OutputFolder folder;
  std::string error;
  EXPECT_FALSE(folder.Begin(root + "/out", {}, {}, &error));
  EXPECT_NE(error.find("symbolic link"), std::string::npos) << error;
  EXPECT_TRUE(fs::is_symlink(root + "/out"));
  EXPECT_TRUE(fs::exists(root + "/real/run.json"));
  EXPECT_EQ(Entries(root), (std::vector<std::string>{"out", "real"}));
}

}  // namespace
}  // namespace ccdpsf
