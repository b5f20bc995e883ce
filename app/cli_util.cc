#include "app/cli_util.h"

#include <sys/resource.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

#include "core/util/error.h"
#include "core/util/options.h"

namespace avatar::app {

std::string Fixed(double value, int digits) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), "%.*f", digits, value);
  return buffer;
}

std::vector<std::string> SplitList(const std::string& text) {
  std::vector<std::string> parts;
  std::stringstream stream(text);
  std::string item;
  while (std::getline(stream, item, ',')) {
    if (!item.empty()) parts.push_back(item);
  }
  return parts;
}

double PeakRssMb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<double>(usage.ru_maxrss) / 1024.0;  // Linux reports kilobytes.
}

double Median(std::vector<double> values) {
  AVATAR_CHECK_INPUT(!values.empty()) << "the median of no values is undefined";
  std::sort(values.begin(), values.end());
  const size_t n = values.size();
  return n % 2 == 1 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

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
