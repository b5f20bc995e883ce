#include "app/cli_util.h"

#include <cmath>

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

}  // namespace avatar::app
