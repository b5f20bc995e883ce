#include "core/io/atomic_file.h"

#include <signal.h>
#include <unistd.h>

#include <cerrno>

#include <atomic>
#include <fstream>
#include <mutex>
#include <set>
#include <sstream>
#include <vector>

#include "core/util/error.h"

namespace avatar {
namespace fs = std::filesystem;

namespace {

fs::path TempPathFor(const fs::path& target) {
  static std::atomic<unsigned> counter{0};
  std::ostringstream name;
  // The temporary keeps the target's extension so that writers choosing a format by
  // extension (OpenCV, FFmpeg) still pick the right one.
  name << "." << target.stem().string() << ".tmp" << ::getpid() << "_" << counter++ << target.extension().string();
  return target.parent_path() / name.str();
}

// The process id in a work-file name: `prefix` then "<pid>_"; 0 when the name does not match.
pid_t WorkFilePid(const std::string& name, const std::string& prefix) {
  if (name.size() <= prefix.size() || name.compare(0, prefix.size(), prefix) != 0) return 0;
  size_t i = prefix.size();
  int64_t pid = 0;
  while (i < name.size() && name[i] >= '0' && name[i] <= '9' && pid < (int64_t{1} << 31)) pid = pid * 10 + (name[i++] - '0');
  if (i == prefix.size() || i >= name.size() || name[i] != '_' || pid >= (int64_t{1} << 31)) return 0;
  return static_cast<pid_t>(pid);
}

bool ProcessRuns(pid_t pid) { return ::kill(pid, 0) == 0 || errno == EPERM; }

}  // namespace

int CleanStaleWorkFiles(const fs::path& target) {
  const fs::path parent = target.parent_path().empty() ? fs::path(".") : target.parent_path();
  {
    static std::mutex mutex;
    static std::set<std::string> scanned;
    std::error_code ec;
    const fs::path key = fs::weakly_canonical(fs::absolute(parent, ec), ec);
    std::lock_guard<std::mutex> lock(mutex);
    if (!scanned.insert(key.string() + "\n" + target.stem().string()).second) return 0;
  }
  const std::string stem = "." + target.stem().string();
  std::vector<fs::path> stale;
  std::error_code ec;
  for (fs::directory_iterator it(parent, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    for (const char* marker : {".tmp", ".part"}) {
      const pid_t pid = WorkFilePid(name, stem + marker);
      if (pid > 0 && pid != ::getpid() && !ProcessRuns(pid)) stale.push_back(it->path());
    }
  }
  int handled = 0;
  for (const fs::path& path : stale) {
    const std::string name = path.filename().string();
    const bool old_copy = name.size() > 4 && name.compare(name.size() - 4, 4, ".old") == 0;
    std::error_code step;
    if (old_copy && !fs::exists(target, step)) {
      fs::rename(path, target, step);
    } else {
      fs::remove_all(path, step);
    }
    handled += step ? 0 : 1;
  }
  return handled;
}

void WriteFileAtomically(const fs::path& target, const std::function<void(const fs::path&)>& write) {
  const fs::path parent = target.parent_path().empty() ? fs::path(".") : target.parent_path();
  std::error_code ec;
  if (!fs::is_directory(parent, ec)) {
    throw Io("cannot write '" + target.string() + "': folder '" + parent.string() +
             "' does not exist; create it or choose another output path");
  }
  CleanStaleWorkFiles(target);
  const fs::path temp = TempPathFor(target.parent_path().empty() ? fs::path(".") / target : target);
  try {
    write(temp);
  } catch (...) {
    fs::remove(temp, ec);
    throw;
  }
  if (!fs::exists(temp, ec)) {
    throw Io("writing '" + target.string() + "' produced no file (disk full or permission denied?)");
  }
  fs::rename(temp, target, ec);
  if (ec) {
    fs::remove(temp, ec);
    throw Io("cannot move the finished file to '" + target.string() + "': " + ec.message());
  }
}

void WriteBytesAtomically(const fs::path& target, const std::string& bytes) {
  WriteFileAtomically(target, [&](const fs::path& temp) {
    std::ofstream out(temp, std::ios::binary | std::ios::trunc);
    if (!out) throw Io("cannot open '" + temp.string() + "' for writing; check permissions and free space");
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    out.flush();
    if (!out) throw Io("writing '" + temp.string() + "' failed; check free disk space");
  });
}

std::string ReadFileBytes(const fs::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Io("file not found: '" + path.string() + "'; check the path");
  if (fs::is_directory(path, ec)) throw Io("'" + path.string() + "' is a folder, not a file");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Io("cannot read '" + path.string() + "'; check its permissions");
  std::ostringstream buffer;
  buffer << in.rdbuf();
  if (in.bad()) throw Io("reading '" + path.string() + "' failed");
  return buffer.str();
}

}  // namespace avatar
