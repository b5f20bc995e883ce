#include "core/io/atomic_file.h"

#include <unistd.h>

#include <atomic>
#include <fstream>
#include <sstream>

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

}  // namespace

void WriteFileAtomically(const fs::path& target, const std::function<void(const fs::path&)>& write) {
  const fs::path parent = target.parent_path().empty() ? fs::path(".") : target.parent_path();
  std::error_code ec;
  if (!fs::is_directory(parent, ec)) {
    throw Io("cannot write '" + target.string() + "': folder '" + parent.string() +
             "' does not exist; create it or choose another output path");
  }
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
