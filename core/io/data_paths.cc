#include "core/io/data_paths.h"

#include <cstdlib>

#include "core/util/error.h"

namespace avatar {
namespace fs = std::filesystem;

DataPaths DataPaths::Resolve(const std::string& option) {
  DataPaths paths;
  if (!option.empty()) {
    paths.root_ = option;
    paths.source_ = "option";
  } else if (const char* env = std::getenv("AVATAR_DATA_DIR"); env != nullptr && *env != '\0') {
    paths.root_ = env;
    paths.source_ = "AVATAR_DATA_DIR";
  } else {
    fs::path cache;
    if (const char* xdg = std::getenv("XDG_CACHE_HOME"); xdg != nullptr && *xdg != '\0') {
      cache = xdg;
    } else if (const char* home = std::getenv("HOME"); home != nullptr && *home != '\0') {
      cache = fs::path(home) / ".cache";
    } else {
      cache = fs::temp_directory_path();
    }
    paths.root_ = cache / "avatar-studio";
    paths.source_ = "default cache";
  }
  return paths;
}

fs::path DataPaths::Require(const std::string& relative, const std::string& purpose) const {
  const fs::path full = root_ / relative;
  std::error_code ec;
  if (fs::exists(full, ec)) return full;
  throw MissingData("missing data file '" + full.string() + "' (" + purpose + "). The data folder '" +
                    root_.string() + "' comes from the " + source_ +
                    ". Install the data with scripts/setup (as root, or with sudo), or point --data-dir or "
                    "AVATAR_DATA_DIR at a folder that holds it.");
}

}  // namespace avatar
