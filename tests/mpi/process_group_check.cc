// ProcessGroup in a real MPI job of two ranks: run as `mpirun -np 2 process_group_check`
// (ctest: process_group_mpi). Each rank checks what it receives against texts it computes
// itself from the same recipe (TextFor), prints every failed check to stderr with its rank,
// and exits 1 if any failed; mpirun then exits non-zero.
#include <cstdint>
#include <cstdio>
#include <limits>
#include <string>
#include <vector>

#include "ccdpsf/process_group.h"

namespace {

int failures = 0;

void Expect(bool ok, int rank, const std::string& what) {
  if (ok) return;
  ++failures;
  std::fprintf(stderr, "process_group_check: rank %d: FAILED: %s\n", rank, what.c_str());
}

// A text that depends on (rank, round) in every byte, with every byte value including '\0',
// so that a text delivered to the wrong slot, shifted, cut short or padded differs. From a
// 64-bit linear congruential generator (Knuth's MMIX constants); only determinism matters.
std::string TextFor(int rank, int round, std::size_t length) {
  std::uint64_t state = 0x9E3779B97F4A7C15ULL * static_cast<std::uint64_t>(rank * 131 + round + 1);
  std::string text(length, '\0');
  for (char& c : text) {
    state = state * 6364136223846793005ULL + 1442695040888963407ULL;
    c = static_cast<char>(state >> 56);
  }
  return text;
}

// Where two texts first differ, for the failure message.
std::string Difference(const std::string& got, const std::string& want) {
  if (got.size() != want.size()) {
    return "length " + std::to_string(got.size()) + ", expected " + std::to_string(want.size());
  }
  for (std::size_t i = 0; i < got.size(); ++i) {
    if (got[i] != want[i]) return "first difference at byte " + std::to_string(i);
  }
  return "equal";
}

// One gather round: rank r sends TextFor(r, round, lengths[r]); rank 0 must receive them all
// in rank order, rank 1 nothing.
void CheckGather(ccdpsf::ProcessGroup& group, int round, const std::vector<std::size_t>& lengths) {
  const int rank = group.rank();
  const std::string mine = TextFor(rank, round, lengths[rank]);
  std::vector<std::string> texts = {"stale"};  // must be replaced (rank 0) or cleared
  std::string error;
  const bool ok = group.GatherToRoot(mine, &texts, &error);
  const std::string where = "GatherToRoot round " + std::to_string(round);
  Expect(ok, rank, where + " returned false: " + error);
  if (rank != 0) {
    Expect(texts.empty(), rank,
           where + ": a non-root rank received " + std::to_string(texts.size()) + " texts");
    return;
  }
  Expect(texts.size() == lengths.size(), rank,
         where + ": " + std::to_string(texts.size()) + " texts on rank 0, expected " +
             std::to_string(lengths.size()));
  for (std::size_t r = 0; r < texts.size() && r < lengths.size(); ++r) {
    const std::string want = TextFor(static_cast<int>(r), round, lengths[r]);
    Expect(texts[r] == want, rank,
           where + ", text of rank " + std::to_string(r) + ": " + Difference(texts[r], want));
  }
}

void CheckBroadcast(ccdpsf::ProcessGroup& group, int round, std::size_t length) {
  const int rank = group.rank();
  const std::string root_text = TextFor(0, round, length);
  // Rank 1 starts with a longer text of its own, which must be replaced, not overwritten.
  std::string text = rank == 0 ? root_text : TextFor(rank, round, length + 1000);
  std::string error;
  const std::string where = "Broadcast of " + std::to_string(length) + " bytes";
  Expect(group.Broadcast(&text, &error), rank, where + " returned false: " + error);
  Expect(text == root_text, rank, where + ": " + Difference(text, root_text));
}

}  // namespace

int main() {
  ccdpsf::ProcessGroup& group = ccdpsf::ProcessGroup::Get();
  const int rank = group.rank();

  Expect(!group.launched_without_mpi_support(), rank,
         "launched_without_mpi_support: " + group.launch_error());
  Expect(group.mpi_initialised(), rank, "mpi_initialised() is false under mpirun");
  Expect(group.distributed(), rank, "distributed() is false with two ranks");
  if (group.size() != 2 || rank < 0 || rank > 1) {
    // The checks below assume ranks 0 and 1; every rank sees the same size, so all stop here.
    Expect(false, rank,
           "rank " + std::to_string(rank) + " of " + std::to_string(group.size()) +
               ", expected rank 0 or 1 of 2");
    group.Finalize();
    return 1;
  }

  // Distinct ranks: rank 0 must receive "0" then "1".
  std::vector<std::string> ranks;
  std::string error;
  Expect(group.GatherToRoot(std::to_string(rank), &ranks, &error), rank,
         "GatherToRoot of the ranks: " + error);
  if (rank == 0) {
    Expect(ranks == std::vector<std::string>({"0", "1"}), rank,
           "ranks gathered on rank 0 are not {0, 1}");
  }

  // Lengths of 0 bytes, 1 MiB + 7 (more than Open MPI's shared-memory eager limit, so the
  // large-message path is used), and small unequal ones, in both orders.
  const std::size_t kLarge = (std::size_t{1} << 20) + 7;
  CheckGather(group, 1, {0, kLarge});
  CheckGather(group, 2, {kLarge, 0});
  CheckGather(group, 3, {17, 3});
  CheckGather(group, 4, {0, 0});

  group.Barrier();

  CheckBroadcast(group, 5, 300000);
  CheckBroadcast(group, 6, 0);

  // AllAgree is the logical AND over the ranks, whichever rank disagrees.
  Expect(group.AllAgree(true), rank, "AllAgree(true on both) is false");
  Expect(!group.AllAgree(rank != 1), rank, "AllAgree(false on rank 1) is true");
  Expect(!group.AllAgree(rank != 0), rank, "AllAgree(false on rank 0) is true");
  Expect(!group.AllAgree(false), rank, "AllAgree(false on both) is true");

  // Texts that together exceed one MPI call's 2^31 - 1 bytes (1 GiB + 1 on each rank, so
  // neither alone does): both ranks must refuse, and neither may hang. 1 GiB of memory per
  // rank for a moment.
  {
    const std::size_t half = static_cast<std::size_t>(std::numeric_limits<int>::max()) / 2 + 1;
    std::vector<std::string> texts;
    std::string refusal;
    const bool ok = group.GatherToRoot(std::string(half, 'x'), &texts, &refusal);
    Expect(!ok, rank, "GatherToRoot of 2 x (1 GiB + 1) bytes was not refused");
    Expect(!refusal.empty(), rank, "GatherToRoot refused without a reason");
    Expect(texts.empty(), rank, "GatherToRoot refused but returned texts");
  }

  // The job still works after a refusal.
  CheckGather(group, 7, {5, 11});

  group.Finalize();
  Expect(!group.mpi_initialised(), rank, "mpi_initialised() is true after Finalize()");
  group.Finalize();  // a second call does nothing

  if (failures == 0) std::printf("process_group_check: rank %d: all checks passed\n", rank);
  return failures == 0 ? 0 : 1;
}
