// A run's output folder, replaced as a whole.
//
// A command writes everything into a private folder beside --out (".NAME.ccdpsf-partial"),
// and Commit() swaps it with --out in one step (renameat2 RENAME_EXCHANGE; two renames on
// file systems without it), then removes the earlier run's files. So the files of an earlier
// run never sit beside new ones (a --nomcmc rerun does not keep the old chain.fits), and a
// run that fails or is killed leaves --out as it was.
//
// Because --out is replaced, it must be a folder ccdpsf may replace: one that does not exist,
// an empty one, or an earlier ccdpsf output (it holds a run.json naming ccdpsf). A folder
// with other files, or one that holds an input of the run, is refused before any work; so
// is an --out that is a symbolic link (the link, not its target, would be replaced), that
// belongs to another user, or that the user made read-only (it or a folder inside it), even
// for root: it is left exactly as it was.
//
// The partial folder is created exclusively (mkdir, mode 0700), so nothing planted at its
// predictable name is ever followed: a symbolic link there is refused, not emptied. It is
// locked (flock) while a run writes it: a second run into the same --out is refused. A
// partial folder left by a killed run (a real folder of this user) is taken over by the
// next run (`resumable` says which of its entries may be reused) and removed at Commit().
// Every path the run writes or removes lies inside it (safe_path.h).
#ifndef CCDPSF_OUTPUT_FOLDER_H_
#define CCDPSF_OUTPUT_FOLDER_H_

#include <string>
#include <vector>

namespace ccdpsf {

class OutputFolder {
 public:
  OutputFolder() = default;
  ~OutputFolder();
  OutputFolder(const OutputFolder&) = delete;
  OutputFolder& operator=(const OutputFolder&) = delete;

  // Checks that `out_dir` may be replaced and that none of `inputs` (files or folders the
  // run reads) lies inside it, then creates and locks the partial folder. An earlier
  // partial folder is emptied except for the entries named in `resumable` (kept for the
  // command to reuse). False with a one-line reason.
  bool Begin(const std::string& out_dir, const std::vector<std::string>& inputs,
             const std::vector<std::string>& resumable, std::string* error);

  // Where the run writes its files until Commit().
  const std::string& partial() const { return partial_; }
  // The folder the files will be in after Commit() (for messages and recorded paths).
  const std::string& out_dir() const { return out_dir_; }

  // Replaces out_dir by the partial folder, without the entries named in `drop` (working
  // files such as a resume cache). False with a reason (out_dir is then as it was).
  bool Commit(const std::vector<std::string>& drop, std::string* error);

  // Leaves the partial folder in place (for a later run to resume from) instead of
  // removing it when this object is destroyed without Commit().
  void KeepForResume() { keep_ = true; }

 private:
  std::string out_dir_;
  std::string partial_;
  int lock_fd_ = -1;
  bool keep_ = false;
};

// True if `dir` is a ccdpsf output folder: it holds a run.json written by ccdpsf.
bool IsCcdpsfOutput(const std::string& dir);

}  // namespace ccdpsf

#endif  // CCDPSF_OUTPUT_FOLDER_H_
