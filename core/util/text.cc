#include "core/util/text.h"

#include <cmath>
#include <cstdio>
#include <sstream>

namespace avatar {

std::string Fixed(double value, int digits) {
  if (std::isnan(value)) return "n/a";
  if (std::isinf(value)) return value > 0 ? "inf" : "-inf";
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

std::string FixedOrDash(double value, int digits) { return std::isfinite(value) ? Fixed(value, digits) : "-"; }

}  // namespace avatar
