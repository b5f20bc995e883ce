#include "core/io/data_paths.h"

#include <cstdlib>

#include "core/io/resources.h"
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
    // An installed package carries the data under <prefix>/share/avatar-studio; it is used when
    // the user's cache holds no data (a cache filled by scripts/setup still wins).
    std::error_code ec;
    if (!fs::exists(paths.root_ / "models", ec)) {
      const fs::path installed = InstalledDataDir();
      if (!installed.empty() && fs::exists(installed / "models", ec)) {
        paths.root_ = installed;
        paths.source_ = "installed package";
      }
    }
  }
  return paths;
}

fs::path DataPaths::Require(const std::string& relative, const std::string& purpose) const {
  const fs::path full = root_ / relative;
  std::error_code ec;
  if (fs::exists(full, ec)) return full;
  if (source_ == "installed package") {
    throw MissingData("missing data file '" + full.string() + "' (" + purpose + ") in the installed data folder '" +
                      root_.string() + "'. Reinstall the avatar-studio package (apt-get install --reinstall "
                      "avatar-studio), or point --data-dir or AVATAR_DATA_DIR at a data folder that holds it.");
  }
  throw MissingData("missing data file '" + full.string() + "' (" + purpose + "). The data folder '" +
                    root_.string() + "' comes from the " + source_ +
                    ". Install the avatar-studio package, or fill the folder with the source tree's scripts/setup "
                    "(as root, or with sudo), or point --data-dir or AVATAR_DATA_DIR at a folder that holds it.");
}

}  // namespace avatar
