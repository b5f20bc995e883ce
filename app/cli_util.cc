#include "app/cli_util.h"

#include <cmath>
#include <sstream>

#include "core/util/error.h"
#include "core/util/options.h"

namespace avatar::app {

std::map<std::string, float> ParseControlFlags(const std::vector<std::string>& entries) {
  std::map<std::string, float> controls;
  for (const auto& entry : entries) {
    const size_t eq = entry.find('=');
    AVATAR_CHECK_OPTION(eq != std::string::npos && eq > 0 && eq + 1 < entry.size())
        << "--expr expects name=value, got '" << entry << "'";
    float value = 0.0f;
    options::ParseValue("--expr " + entry.substr(0, eq), entry.substr(eq + 1), value);
    AVATAR_CHECK_OPTION(std::isfinite(value)) << "--expr " << entry << ": value must be finite";
    controls[entry.substr(0, eq)] = value;
  }
  return controls;
}

Expression ParseExpressionFlags(const std::vector<std::string>& entries) {
  Expression e;
  e.controls = ParseControlFlags(entries);
  return e;
}

const std::vector<RenamedFlag>& RenamedFlags() {
  static const std::vector<RenamedFlag> table = {
      {"animate", "--preset", "--config"},          // network size (BackendOptions::config)
      {"render", "--preset", "--mode"},             // render mode of one frame (RenderMode)
      {"bench render", "--presets", "--cases"},     // the render benchmark's cases
      {"bench accuracy", "--presets", "--quality"}, // quality levels (QualityLevel)
  };
  return table;
}

std::vector<std::string> RewriteRenamedFlags(const std::vector<std::string>& args, std::ostream& warnings) {
  std::vector<std::string> out = args;
  for (const RenamedFlag& r : RenamedFlags()) {
    // The command words must open the line.
    std::istringstream words(r.command);
    size_t first_flag = 0;
    bool match = true;
    for (std::string word; words >> word; ++first_flag) {
      if (first_flag >= out.size() || out[first_flag] != word) {
        match = false;
        break;
      }
    }
    if (!match) continue;
    const std::string old_flag = r.old_flag;
    for (size_t i = first_flag; i < out.size(); ++i) {
      std::string& a = out[i];
      if (a == "--") break;
      const bool bare = a == old_flag;
      if (!bare && a.rfind(old_flag + "=", 0) != 0) continue;
      a = r.new_flag + a.substr(old_flag.size());
      warnings << "warning: `" << r.command << " " << r.old_flag << "` is deprecated and will be removed after "
               << kRenamedFlagsRemovedAfter << "; use " << r.new_flag << "\n";
    }
  }
  return out;
}

}  // namespace avatar::app
