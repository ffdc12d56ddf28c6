// A loop over indices spread across threads: the one worker-pool pattern of the MAP search's
// screening, trend's group fits and diagnose's simulated statistics.
#ifndef CCDPSF_INTERNAL_PARALLEL_FOR_H_
#define CCDPSF_INTERNAL_PARALLEL_FOR_H_

#include <functional>

namespace ccdpsf::internal {

// Calls task(index, worker) once for every index in [0, n), in increasing order of start, on
// min(threads, n) threads (the calling thread is worker 0; at least one). Each index goes to
// the next free worker, so long and short tasks mix well; worker (in [0, threads)) lets a task
// keep state per thread, since one worker runs one task at a time. Returns when all are done.
// Results must be stored by index: which worker runs which index varies from run to run.
// If the system refuses a thread, fewer workers run the indices.
void ParallelFor(int n, int threads, const std::function<void(int index, int worker)>& task);

}  // namespace ccdpsf::internal

#endif  // CCDPSF_INTERNAL_PARALLEL_FOR_H_
