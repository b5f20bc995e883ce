#include "fuzz_common.h"

#include <cstdlib>
#include <fstream>
#include <iterator>
#include <stdexcept>

#include "core/util/error.h"

namespace avatar::fuzz {
namespace fs = std::filesystem;

std::vector<Target>& Targets() {
  static std::vector<Target> targets;
  return targets;
}

bool Register(Target target) {
  Targets().push_back(std::move(target));
  return true;
}

namespace {

fs::path MakeProcessTempDir() {
  std::string pattern = (fs::temp_directory_path() / "avatar-fuzz-XXXXXX").string();
  if (mkdtemp(pattern.data()) == nullptr) throw std::runtime_error("mkdtemp failed for " + pattern);
  return pattern;
}

struct TempDirOwner {
  fs::path path = MakeProcessTempDir();
  ~TempDirOwner() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
};

std::string SafeName(std::string name, size_t index) {
  const std::string fallback = "part" + std::to_string(index);
  if (name.empty() || name.size() > 80) return fallback;
  int slashes = 0;
  for (char c : name) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '.' ||
                    c == '_' || c == '-' || c == '/';
    if (!ok) return fallback;
    if (c == '/') ++slashes;
  }
  if (slashes > 1 || name.front() == '/' || name.back() == '/' || name.front() == '.') return fallback;
  for (const auto& piece : fs::path(name)) {
    if (piece == "." || piece == ".." || piece.empty()) return fallback;
  }
  return name;
}

}  // namespace

const fs::path& ProcessTempDir() {
  static TempDirOwner owner;
  return owner.path;
}

fs::path FreshInputDir() {
  const fs::path dir = ProcessTempDir() / "input";
  std::error_code ec;
  fs::remove_all(dir, ec);
  fs::create_directories(dir);
  return dir;
}

void WriteFile(const fs::path& path, std::string_view bytes) {
  if (path.has_parent_path()) fs::create_directories(path.parent_path());
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  if (!out) throw std::runtime_error("cannot write " + path.string());
}

std::string ReadFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("cannot read " + path.string());
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

std::vector<std::pair<std::string, std::string>> SplitParts(std::string_view input, const std::string& first_name) {
  std::vector<std::pair<std::string, std::string>> parts;
  size_t pos = input.find(kPartSeparator);
  parts.emplace_back(first_name, std::string(input.substr(0, pos)));
  while (pos != std::string_view::npos) {
    const size_t start = pos + kPartSeparator.size();
    const size_t line_end = input.find('\n', start);
    const size_t next = input.find(kPartSeparator, start);
    std::string name;
    size_t body = start;
    if (line_end != std::string_view::npos && (next == std::string_view::npos || line_end < next)) {
      name = std::string(input.substr(start, line_end - start));
      body = line_end + 1;
    }
    const size_t end = next == std::string_view::npos ? input.size() : next;
    std::string safe = SafeName(name, parts.size());
    for (const auto& p : parts) {
      if (p.first == safe) safe = "part" + std::to_string(parts.size());
    }
    parts.emplace_back(safe, std::string(input.substr(body, end > body ? end - body : 0)));
    pos = next;
  }
  return parts;
}

std::string JoinParts(const std::vector<std::pair<std::string, std::string>>& parts) {
  std::string out;
  for (size_t i = 0; i < parts.size(); ++i) {
    if (i > 0) {
      out += kPartSeparator;
      out += parts[i].first;
      out += '\n';
    }
    out += parts[i].second;
  }
  return out;
}

fs::path WriteParts(const fs::path& dir, const std::vector<std::pair<std::string, std::string>>& parts) {
  for (const auto& [name, bytes] : parts) {
    std::error_code ec;
    // A part named like an earlier part's folder (or the reverse) is dropped, not an error.
    if (fs::exists(dir / name, ec)) continue;
    try {
      WriteFile(dir / name, bytes);
    } catch (const std::exception&) {
    }
  }
  return dir / parts.front().first;
}

fs::path DataDir() {
  fs::path dir;
  if (const char* env = std::getenv("AVATAR_DATA_DIR"); env != nullptr && *env != '\0') {
    dir = env;
  } else if (const char* cache = std::getenv("XDG_CACHE_HOME"); cache != nullptr && *cache != '\0') {
    dir = fs::path(cache) / "avatar-studio";
  } else if (const char* home = std::getenv("HOME"); home != nullptr) {
    dir = fs::path(home) / ".cache" / "avatar-studio";
  }
  std::error_code ec;
  return !dir.empty() && fs::is_directory(dir, ec) ? dir : fs::path();
}

std::string WithArchiveChecksum(std::string_view input) {
  std::string bytes(input);
  // magic 8 + version 4 + header length 8 + data length 8 + checksum 8
  if (bytes.size() < 36) return bytes;
  // The archive's offset basis (core/model/checkpoint.cc), which is not FNV's usual 14695981039346656037.
  uint64_t hash = 1469598103934665603ULL;
  for (size_t i = 0; i + 8 < bytes.size(); ++i) {
    hash ^= static_cast<uint8_t>(bytes[i]);
    hash *= 0x100000001b3ULL;
  }
  for (int k = 0; k < 8; ++k) bytes[bytes.size() - 8 + k] = static_cast<char>((hash >> (8 * k)) & 0xff);
  return bytes;
}

std::string AcceptAvatarErrors(const std::function<void()>& parse) {
  try {
    parse();
  } catch (const avatar::Error& e) {
    return std::string(e.Kind()) + ": " + e.what();
  }
  return {};
}

}  // namespace avatar::fuzz
