#pragma once
// Finds the packaged data (face models, mesh topology, sample portraits and clips) that
// scripts/setup installs. One resolver for the whole app: an explicit option wins, then
// the AVATAR_DATA_DIR environment variable, then the default cache folder
// ($XDG_CACHE_HOME/avatar-studio or ~/.cache/avatar-studio) when it holds data, then the copy an
// installed package carries (InstalledDataDir(), <prefix>/share/avatar-studio), then the default
// cache again (so that the missing-data error names it).

#include <filesystem>
#include <string>

namespace avatar {

class DataPaths {
 public:
  // `option` is the --data-dir value ("" when not given).
  static DataPaths Resolve(const std::string& option = {});

  const std::filesystem::path& Root() const { return root_; }
  // Where the root came from: "option", "AVATAR_DATA_DIR", "default cache" or "installed package".
  const std::string& Source() const { return source_; }

  // Returns Root()/relative if it exists; otherwise throws MissingData saying which file is
  // missing, what it is for, and the command that installs it.
  std::filesystem::path Require(const std::string& relative, const std::string& purpose) const;
  // Root()/relative, without checking.
  std::filesystem::path Path(const std::string& relative) const { return root_ / relative; }

  // The bundled default portrait and driving clip (relative paths under Root()).
  static constexpr const char* kDefaultPortrait = "samples/grace_hopper.jpg";
  static constexpr const char* kDefaultDriver = "samples/franck.mp4";

 private:
  std::filesystem::path root_;
  std::string source_;
};

}  // namespace avatar
