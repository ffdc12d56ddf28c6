#include "ccdpsf/process_group.h"

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <limits>

// CCDPSF_HAVE_MPI is defined for this file alone (CMakeLists.txt) when the build found MPI;
// nothing else in ccdpsf includes mpi.h.
#if CCDPSF_HAVE_MPI
// Compiled as C++, mpi.h would also declare MPI's long-removed C++ bindings, whose code lives
// in a separate library (libmpi_cxx) we do not link; only the C API is used here.
#define OMPI_SKIP_MPICXX 1
#define MPICH_SKIP_MPICXX 1
#include <mpi.h>
#endif

namespace ccdpsf {

namespace {

// The name of the variable that shows an MPI launcher started this process, or nullptr.
const char* LauncherVariable() {
  for (const char* name : {"OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_SIZE"}) {
    const char* value = std::getenv(name);
    if (value != nullptr && value[0] != '\0') return name;
  }
  return nullptr;
}

#if CCDPSF_HAVE_MPI
// One MPI call carries at most INT_MAX elements (counts and displacements are int).
constexpr std::uint64_t kMaxMessageBytes =
    static_cast<std::uint64_t>(std::numeric_limits<int>::max());

// MPI's default error handler (MPI_ERRORS_ARE_FATAL) ends the job before a failing call
// returns; this is for an MPI that returns the error anyway.
void CheckMpi(int code, const char* what) {
  if (code == MPI_SUCCESS) return;
  char text[MPI_MAX_ERROR_STRING] = {0};
  int length = 0;
  MPI_Error_string(code, text, &length);
  std::fprintf(stderr, "ccdpsf: %s failed: %s\n", what, text);
  MPI_Abort(MPI_COMM_WORLD, 1);
  std::_Exit(1);
}
#endif

}  // namespace

ProcessGroup& ProcessGroup::Get() {
  // Allocated once and never deleted: no destructor runs among the static destructors, where
  // the order against MPI's own clean-up at exit is unknown.
  static ProcessGroup* const group = new ProcessGroup();
  return *group;
}

ProcessGroup::ProcessGroup() {
  const char* launcher = LauncherVariable();
  if (launcher == nullptr) return;  // this process alone: never touch MPI
#if CCDPSF_HAVE_MPI
  int provided = MPI_THREAD_SINGLE;
  if (MPI_Init_thread(nullptr, nullptr, MPI_THREAD_FUNNELED, &provided) != MPI_SUCCESS) {
    std::fprintf(stderr, "ccdpsf: cannot join the MPI job (%s is set): MPI_Init_thread failed\n",
                 launcher);
    std::exit(1);
  }
  mpi_state_ = MpiState::kJoined;
  mpi_thread_ = std::this_thread::get_id();
  if (provided < MPI_THREAD_FUNNELED) {
    std::fprintf(stderr,
                 "ccdpsf: the MPI library offers no thread support (MPI_THREAD_FUNNELED "
                 "needed, level %d given)\n",
                 provided);
    MPI_Abort(MPI_COMM_WORLD, 1);
    std::_Exit(1);
  }
  CheckMpi(MPI_Comm_rank(MPI_COMM_WORLD, &rank_), "MPI_Comm_rank");
  CheckMpi(MPI_Comm_size(MPI_COMM_WORLD, &size_), "MPI_Comm_size");
#else
  launch_error_ = std::string("started by an MPI launcher (") + launcher +
                  " is set), but this ccdpsf was built without MPI: rebuild it with Open MPI "
                  "(libopenmpi-dev) and CCDPSF_MPI=ON, or run it without mpirun";
#endif
}

bool ProcessGroup::mpi_initialised() const {
#if CCDPSF_HAVE_MPI
  int initialised = 0;
  int finalised = 0;
  MPI_Initialized(&initialised);
  MPI_Finalized(&finalised);
  return initialised != 0 && finalised == 0;
#else
  return false;
#endif
}

bool ProcessGroup::UseMpi(const char* what) const {
  switch (mpi_state_) {
    case MpiState::kNotJoined:
      return false;
    case MpiState::kFinalised:
      std::fprintf(stderr, "ccdpsf: ProcessGroup::%s called after Finalize()\n", what);
      std::abort();
    case MpiState::kJoined:
      break;
  }
  if (std::this_thread::get_id() != mpi_thread_) {
    std::fprintf(stderr,
                 "ccdpsf: ProcessGroup::%s called from a thread other than the one that "
                 "joined the MPI job\n",
                 what);
#if CCDPSF_HAVE_MPI
    MPI_Abort(MPI_COMM_WORLD, 1);
#endif
    std::abort();
  }
  return true;
}

void ProcessGroup::Barrier() {
  if (!UseMpi("Barrier")) return;
#if CCDPSF_HAVE_MPI
  CheckMpi(MPI_Barrier(MPI_COMM_WORLD), "MPI_Barrier");
#endif
}

bool ProcessGroup::GatherToRoot(const std::string& text, std::vector<std::string>* texts,
                                std::string* error) {
  texts->clear();
  if (!UseMpi("GatherToRoot")) {
    texts->push_back(text);
    return true;
  }
#if CCDPSF_HAVE_MPI
  // Every rank learns every size (not only rank 0), so that all of them refuse together when
  // the total is too large, instead of the others waiting in MPI_Gatherv for a root that
  // refused.
  const std::uint64_t mine = text.size();
  std::vector<std::uint64_t> sizes(size_);
  CheckMpi(MPI_Allgather(&mine, 1, MPI_UINT64_T, sizes.data(), 1, MPI_UINT64_T, MPI_COMM_WORLD),
           "MPI_Allgather");
  std::uint64_t total = 0;
  for (std::uint64_t size : sizes) {
    // Compared before adding, so the sum cannot wrap.
    if (size > kMaxMessageBytes - total) {
      *error = "the ranks' texts together exceed " + std::to_string(kMaxMessageBytes) +
               " bytes, the most one MPI gather carries";
      return false;
    }
    total += size;
  }
  std::vector<int> counts;
  std::vector<int> offsets;
  std::string joined;
  if (rank_ == 0) {
    counts.resize(size_);
    offsets.resize(size_);
    int offset = 0;
    for (int r = 0; r < size_; ++r) {
      counts[r] = static_cast<int>(sizes[r]);
      offsets[r] = offset;
      offset += counts[r];
    }
    joined.resize(total);
  }
  CheckMpi(MPI_Gatherv(text.data(), static_cast<int>(mine), MPI_BYTE, joined.data(), counts.data(),
                       offsets.data(), MPI_BYTE, 0, MPI_COMM_WORLD),
           "MPI_Gatherv");
  if (rank_ == 0) {
    texts->reserve(size_);
    for (int r = 0; r < size_; ++r) texts->push_back(joined.substr(offsets[r], counts[r]));
  }
#else
  (void)error;
#endif
  return true;
}

bool ProcessGroup::Broadcast(std::string* text, std::string* error) {
  if (!UseMpi("Broadcast")) return true;
#if CCDPSF_HAVE_MPI
  // The length first, so that every rank sizes its buffer and all refuse a text too large
  // for one call together.
  std::uint64_t length = rank_ == 0 ? text->size() : 0;
  CheckMpi(MPI_Bcast(&length, 1, MPI_UINT64_T, 0, MPI_COMM_WORLD), "MPI_Bcast");
  if (length > kMaxMessageBytes) {
    *error = "rank 0's text is " + std::to_string(length) + " bytes, more than the " +
             std::to_string(kMaxMessageBytes) + " one MPI broadcast carries";
    return false;
  }
  if (rank_ != 0) text->resize(length);
  CheckMpi(MPI_Bcast(text->data(), static_cast<int>(length), MPI_BYTE, 0, MPI_COMM_WORLD),
           "MPI_Bcast");
#else
  (void)text;
  (void)error;
#endif
  return true;
}

bool ProcessGroup::AllAgree(bool ok) {
  if (!UseMpi("AllAgree")) return ok;
  int all = ok ? 1 : 0;
#if CCDPSF_HAVE_MPI
  const int mine = all;
  CheckMpi(MPI_Allreduce(&mine, &all, 1, MPI_INT, MPI_LAND, MPI_COMM_WORLD), "MPI_Allreduce");
#endif
  return all != 0;
}

void ProcessGroup::Finalize() {
  if (mpi_state_ != MpiState::kJoined) return;
  UseMpi("Finalize");  // refuses another thread
#if CCDPSF_HAVE_MPI
  CheckMpi(MPI_Finalize(), "MPI_Finalize");
#endif
  mpi_state_ = MpiState::kFinalised;
}

void ProcessGroup::Abort(int code) {
#if CCDPSF_HAVE_MPI
  if (mpi_state_ == MpiState::kJoined) {
    // From any thread: the job is ending, and MPI_Abort is the only way to end every rank.
    MPI_Abort(MPI_COMM_WORLD, code);
    std::_Exit(code);
  }
#endif
  std::exit(code);
}

}  // namespace ccdpsf
