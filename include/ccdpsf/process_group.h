// The processes one command runs on: this process alone, or the ranks of an MPI job.
//
//   ccdpsf::ProcessGroup& group = ccdpsf::ProcessGroup::Get();
//   if (group.launched_without_mpi_support()) {
//     std::cerr << "ccdpsf: " << group.launch_error() << "\n";
//     return 1;
//   }
//   std::string mine;  // this rank's results, e.g. of the spots i with i % size() == rank()
//   bool ok = group.AllAgree(FitShare(group.rank(), group.size(), &mine));  // same on all
//   std::vector<std::string> all;  // every rank's text in rank order, on rank 0 only
//   std::string error;
//   ok = ok && group.GatherToRoot(mine, &all, &error);
//   if (ok && group.rank() == 0) ok = WriteMap(all, &error);
//   group.Finalize();  // on every path out, once no collective follows
//   return ok ? 0 : 1;
//
// Started normally (`ccdpsf grid ...`), the group is this process alone: rank 0 of 1, and no
// MPI function is called (but the two queries of mpi_initialised()), so ordinary commands,
// tests and the sanitizer build neither need nor touch an MPI engine. (MPI_Init outside a
// launcher would make Open MPI start a "singleton" job with a daemon of its own: 0.27 s
// here, for nothing.)
//
// Started by an MPI launcher (`mpirun -np 4 ccdpsf grid ...`), the group is the job's ranks.
// The launcher is recognised by the environment it gives each process:
//   OMPI_COMM_WORLD_SIZE   Open MPI's mpirun / mpiexec
//   PMIX_RANK              PMIx launchers (Slurm's srun --mpi=pmix, PRRTE; Open MPI too)
//   PMI_SIZE               PMI-1/2 launchers (Slurm's srun --mpi=pmi2, MPICH's Hydra)
// If one of them is set but this build has no MPI (CCDPSF_MPI=OFF, or Open MPI's headers
// missing at configure time), launched_without_mpi_support() is true and the group is rank 0
// of 1: the caller must refuse to run, or N copies would each do all the work.
//
// The group is made, and the MPI job joined, lazily by the first Get(): only a command that
// shards its work (ccdpsf grid) ever joins, the others start exactly as without MPI, and
// the command joins after its own flags are parsed, in main()'s thread. MPI is joined with
// MPI_THREAD_FUNNELED: every call below must come from the thread that made that first call;
// worker threads may run alongside but never call the group. A call from another thread in
// an MPI job is a programming error: one line on stderr and MPI_Abort.
//
// Every collective (Barrier, GatherToRoot, Broadcast, AllAgree) must be reached by every rank
// in the same order. A rank that fails alone therefore does not return early: it reports
// through AllAgree(false) so that every rank stops at the same point, or, when it cannot go
// on at all, calls Abort(), which ends the whole job. MPI's own failures (a rank lost, a
// network error) end the whole job too, under MPI's default error handler: no rank waits
// forever for another that has gone.
#ifndef CCDPSF_PROCESS_GROUP_H_
#define CCDPSF_PROCESS_GROUP_H_

#include <string>
#include <thread>
#include <vector>

namespace ccdpsf {

class ProcessGroup {
 public:
  // The group of this process, created (and the MPI job joined, when launched by one) on the
  // first call. Never destroyed: nothing of it runs among the static destructors.
  static ProcessGroup& Get();

  ProcessGroup(const ProcessGroup&) = delete;
  ProcessGroup& operator=(const ProcessGroup&) = delete;

  // This process's index, 0..size()-1, and the number of processes in the group.
  int rank() const { return rank_; }
  int size() const { return size_; }
  // True when more than one process shares the work.
  bool distributed() const { return size_ > 1; }
  // True while MPI is initialised in this process: after joining an MPI job (also with
  // `mpirun -np 1`), until Finalize(). MPI's own answer (MPI_Initialized, MPI_Finalized: the
  // two calls allowed at any time, which start nothing), so tests can check that no MPI
  // engine was started in a process no launcher started.
  bool mpi_initialised() const;

  // Started by an MPI launcher, but this build has no MPI: the caller must not go on.
  bool launched_without_mpi_support() const { return !launch_error_.empty(); }
  // The one-line reason for launched_without_mpi_support(); empty otherwise.
  const std::string& launch_error() const { return launch_error_; }

  // Returns once every rank has called it.
  void Barrier();

  // On rank 0, `texts` becomes every rank's `text` in rank order; on the others it is
  // cleared. In an MPI job, false with the same reason on every rank if the texts together
  // exceed what one MPI call carries (2^31 - 1 bytes); nothing is sent then.
  bool GatherToRoot(const std::string& text, std::vector<std::string>* texts, std::string* error);

  // Rank 0's `text` replaces `text` on every other rank (rank 0's own is left as it is).
  // In an MPI job, false with the same reason on every rank if it exceeds 2^31 - 1 bytes.
  bool Broadcast(std::string* text, std::string* error);

  // The logical AND of `ok` over all ranks: false everywhere if any rank passes false.
  bool AllAgree(bool ok);

  // Leaves the MPI job (MPI_Finalize). Call it on every rank, on every path out of the
  // command, once no collective follows. Safe to call more than once; does nothing without
  // MPI. Deliberately not called at exit on the caller's behalf: MPI_Finalize waits for every
  // rank, so an automatic one would leave a job hanging for ever when one rank returns early
  // while the others wait for it in a collective. Without it, mpirun ends the whole job and
  // reports that rank ("exiting improperly"), also when Finalize was merely forgotten.
  void Finalize();

  // Ends the process with `code` after a fatal error on this rank. In an MPI job, every
  // rank ends (MPI_Abort; mpirun reports the rank and code), since the others would wait
  // for this one forever; alone, it is std::exit(code).
  [[noreturn]] void Abort(int code);

 private:
  ProcessGroup();
  // True when this call must go through MPI; false for the group of one. Refuses (one line,
  // then abort) a call after Finalize() or from another thread than the one that joined.
  bool UseMpi(const char* what) const;

  enum class MpiState { kNotJoined, kJoined, kFinalised };

  int rank_ = 0;
  int size_ = 1;
  MpiState mpi_state_ = MpiState::kNotJoined;
  std::string launch_error_;
  std::thread::id mpi_thread_;  // the thread that called MPI_Init_thread
};

}  // namespace ccdpsf

#endif  // CCDPSF_PROCESS_GROUP_H_
