// Output folders are replaced as a whole: no file of an earlier run beside new ones, no input
// ever inside a folder that is replaced, no partial folder left behind, no collisions.
#include "ccdpsf/output_folder.h"

#include <sys/file.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

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

TEST(OutputFolder, ReplacesAnEarlierRunAsAWhole) {
  const std::string root = FreshDir("outdir", "replace");
  const std::string out = root + "/out";
  fs::create_directories(out);
  WriteRunRecord(out);
  Touch(out + "/chain.fits");  // of the earlier run only
  OutputFolder folder;
  std::string error;
  ASSERT_TRUE(folder.Begin(out, {}, {}, &error)) << error;
  EXPECT_NE(folder.partial(), out);
  EXPECT_TRUE(fs::exists(out + "/chain.fits"));  // untouched until Commit
  WriteRunRecord(folder.partial());
  Touch(folder.partial() + "/fit.json");
  ASSERT_TRUE(folder.Commit({}, &error)) << error;
  EXPECT_TRUE(fs::exists(out + "/fit.json"));
  EXPECT_FALSE(fs::exists(out + "/chain.fits"));
  // Nothing but the output folder is left beside it.
  int entries = 0;
  for (const auto& e : fs::directory_iterator(root)) entries += e.path() != out;
  EXPECT_EQ(entries, 0);
}

TEST(OutputFolder, AFailedRunLeavesTheEarlierResultsAndNoPartialFolder) {
  const std::string root = FreshDir("outdir", "failed");
  const std::string out = root + "/out";
  fs::create_directories(out);
  WriteRunRecord(out);
  Touch(out + "/fit.json", "earlier");
  std::string partial;
  {
    OutputFolder folder;
    std::string error;
    ASSERT_TRUE(folder.Begin(out, {}, {}, &error)) << error;
    partial = folder.partial();
    Touch(partial + "/fit.json", "half");
  }  // no Commit: the run failed
  EXPECT_FALSE(fs::exists(partial));
  std::ifstream in(out + "/fit.json");
  std::string text;
  in >> text;
  EXPECT_EQ(text, "earlier");
}

TEST(OutputFolder, RefusesFoldersItMayNotReplace) {
  const std::string root = FreshDir("outdir", "refuse");
  std::string error;
  // A folder with someone else's files.
  fs::create_directories(root + "/data");
  Touch(root + "/data/notes.txt");
  {
    OutputFolder folder;
    EXPECT_FALSE(folder.Begin(root + "/data", {}, {}, &error));
    EXPECT_NE(error.find("notes.txt"), std::string::npos) << error;
  }
  // A folder (even an earlier output) holding an input of the run, also through "..".
  fs::create_directories(root + "/sim");
  WriteRunRecord(root + "/sim");
  Touch(root + "/sim/exposure_000.fits");
  {
    OutputFolder folder;
    EXPECT_FALSE(folder.Begin(root + "/sim", {root + "/sim/../sim/exposure_000.fits"}, {}, &error));
    EXPECT_NE(error.find("holds the input"), std::string::npos) << error;
    EXPECT_TRUE(fs::exists(root + "/sim/exposure_000.fits"));
  }
  // A file, and names that are no folder of their own.
  Touch(root + "/file");
  for (const std::string& bad : {root + "/file", std::string("."), root + "/sim/.."}) {
    OutputFolder folder;
    EXPECT_FALSE(folder.Begin(bad, {}, {}, &error)) << bad;
  }
  // New and empty folders are fine.
  fs::create_directories(root + "/empty");
  for (const std::string& good : {root + "/new/deeper", root + "/empty", root + "/slash/"}) {
    OutputFolder folder;
    EXPECT_TRUE(folder.Begin(good, {}, {}, &error)) << error;
    EXPECT_EQ(folder.partial().find("/."), folder.partial().rfind("/.")) << folder.partial();
  }
}

TEST(OutputFolder, AKilledRunsPartialFolderIsTakenOverAndASecondWriterRefused) {
  const std::string root = FreshDir("outdir", "partial");
  const std::string out = root + "/out";
  std::string error;
  std::string partial;
  {
    OutputFolder first;
    ASSERT_TRUE(first.Begin(out, {}, {}, &error)) << error;
    partial = first.partial();
    Touch(partial + "/stale.dat");
    fs::create_directories(partial + "/resume");
    Touch(partial + "/resume/group_a.json");
    // While the first run holds the folder, a second run into the same --out is refused.
    OutputFolder second;
    EXPECT_FALSE(second.Begin(out, {}, {}, &error));
    EXPECT_NE(error.find("another ccdpsf run"), std::string::npos) << error;
    first.KeepForResume();  // as if killed: the folder stays
  }
  ASSERT_TRUE(fs::exists(partial + "/stale.dat"));
  OutputFolder next;
  ASSERT_TRUE(next.Begin(out, {}, {"resume"}, &error)) << error;
  EXPECT_EQ(next.partial(), partial);
  EXPECT_FALSE(fs::exists(partial + "/stale.dat"));
  EXPECT_TRUE(fs::exists(partial + "/resume/group_a.json"));
  WriteRunRecord(partial);
  ASSERT_TRUE(next.Commit({"resume"}, &error)) << error;
  EXPECT_TRUE(fs::exists(out + "/run.json"));
  EXPECT_FALSE(fs::exists(out + "/resume"));
  EXPECT_FALSE(fs::exists(partial));
}

// The binary, end to end: the defects of issue 15 that concern output folders.

TEST(OutputFolderCli, ANoMcmcRerunLeavesNoChainOfTheEarlierRun) {
  const std::string out = FreshDir("outdir", "rerun") + "/fit";
  const std::string file = DemoSet() + "/exposure_000.fits";
  RunResult r = RunCcdpsf("fit --max_steps=300 --target_ess=30 --seed=2 --out=" + out + " " + file);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  ASSERT_TRUE(fs::exists(out + "/chain.fits"));
  r = RunCcdpsf("fit --nomcmc --out=" + out + " " + file);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_TRUE(fs::exists(out + "/fit.json"));
  EXPECT_FALSE(fs::exists(out + "/chain.fits"));
  EXPECT_FALSE(fs::exists(out + "/corner.png"));
}

TEST(OutputFolderCli, FilesOfTheSameNameFromTwoFoldersDoNotCollide) {
  const std::string root = FreshDir("outdir", "collide");
  fs::create_directories(root + "/a");
  fs::create_directories(root + "/b");
  fs::copy_file(DemoSet() + "/exposure_000.fits", root + "/a/exposure_000.fits");
  fs::copy_file(DemoSet() + "/exposure_001.fits", root + "/b/exposure_000.fits");
  const RunResult r = RunCcdpsf("fit --nomcmc --out=" + root + "/out " + root +
                                "/a/exposure_000.fits " + root + "/b/exposure_000.fits");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  std::ifstream in(root + "/out/run.json");
  const nlohmann::json run = nlohmann::json::parse(in);
  const nlohmann::json& folders = run["options"]["folders"];
  ASSERT_EQ(folders.size(), 2u);
  EXPECT_NE(folders[0]["folder"], folders[1]["folder"]);
  for (const auto& f : folders) {
    std::ifstream fit(f["folder"].get<std::string>() + "/fit.json");
    const nlohmann::json j = nlohmann::json::parse(fit);
    EXPECT_EQ(j["exposures"][0]["file"], f["file"]) << f.dump();
  }
}

TEST(OutputFolderCli, AnOutputFolderHoldingTheInputsIsRefused) {
  const std::string file = DemoSet() + "/exposure_000.fits";
  const RunResult r = RunCcdpsf("fit --nomcmc --out=" + DemoSet() + " " + file);
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("holds the input"), std::string::npos) << r.output;
  EXPECT_TRUE(fs::exists(file));
  EXPECT_TRUE(fs::exists(DemoSet() + "/truth.json"));
}

}  // namespace
}  // namespace ccdpsf
