// ProcessGroup in a process that no MPI launcher started (the test runner itself): the group
// is this process alone, every operation acts locally, and MPI is never touched. The
// two-rank behaviour is checked under mpirun by tests/mpi/process_group_check.cc.
#include "ccdpsf/process_group.h"

#include <cstdlib>
#include <string>
#include <vector>

#include "gtest/gtest.h"

namespace ccdpsf {
namespace {

// The variables by which ProcessGroup recognises an MPI launcher (process_group.h). If the
// test runner itself were started by one, these tests would not describe a lone process.
bool StartedByLauncher() {
  for (const char* name : {"OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_SIZE"}) {
    const char* value = std::getenv(name);
    if (value != nullptr && value[0] != '\0') return true;
  }
  return false;
}

TEST(ProcessGroupAlone, IsRankZeroOfOneWithoutMpi) {
  ASSERT_FALSE(StartedByLauncher()) << "run ccdpsf_tests without mpirun";
  ProcessGroup& group = ProcessGroup::Get();
  EXPECT_EQ(&group, &ProcessGroup::Get());  // one group per process
  EXPECT_EQ(group.rank(), 0);
  EXPECT_EQ(group.size(), 1);
  EXPECT_FALSE(group.distributed());
  EXPECT_FALSE(group.launched_without_mpi_support());
  EXPECT_EQ(group.launch_error(), "");
  EXPECT_FALSE(group.mpi_initialised());
}

TEST(ProcessGroupAlone, CollectivesActLocally) {
  ASSERT_FALSE(StartedByLauncher()) << "run ccdpsf_tests without mpirun";
  ProcessGroup& group = ProcessGroup::Get();
  group.Barrier();  // returns at once: there is no other rank to wait for

  // Texts with a '\0' inside and an empty one: carried as bytes, not as C strings.
  for (const std::string& text : {std::string("spot 17\0row", 11), std::string()}) {
    std::vector<std::string> texts = {"stale", "entries"};
    std::string error;
    ASSERT_TRUE(group.GatherToRoot(text, &texts, &error)) << error;
    EXPECT_EQ(texts, std::vector<std::string>({text}));

    std::string broadcast = text;
    ASSERT_TRUE(group.Broadcast(&broadcast, &error)) << error;
    EXPECT_EQ(broadcast, text);
  }

  EXPECT_TRUE(group.AllAgree(true));
  EXPECT_FALSE(group.AllAgree(false));
}

TEST(ProcessGroupAlone, NeverInitialisesMpi) {
  ASSERT_FALSE(StartedByLauncher()) << "run ccdpsf_tests without mpirun";
  ProcessGroup& group = ProcessGroup::Get();
  std::vector<std::string> texts;
  std::string error;
  std::string text = "x";
  group.Barrier();
  group.GatherToRoot(text, &texts, &error);
  group.Broadcast(&text, &error);
  group.AllAgree(true);
  group.Finalize();  // nothing to finalise; must not start MPI either
  group.Finalize();
  EXPECT_FALSE(group.mpi_initialised());
  // Still usable after Finalize(): without MPI there is nothing to leave.
  EXPECT_TRUE(group.AllAgree(true));
  EXPECT_EQ(group.size(), 1);
}

}  // namespace
}  // namespace ccdpsf
