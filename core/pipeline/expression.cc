#include "core/pipeline/expression.h"

#include <cstdio>
#include <sstream>

namespace avatar {
namespace {

std::string Number(float value) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.9g", static_cast<double>(value));  // 9 digits: every float round-trips
  return buf;
}

}  // namespace

std::string Expression::Key() const {
  std::ostringstream key;
  bool first = true;
  for (const auto& [name, value] : controls) {
    if (value == 0.0f) continue;  // an explicit 0 is the neutral value of every control
    key << (first ? "" : ",") << name << "=" << Number(value);
    first = false;
  }
  if (!coefficients.empty()) {
    key << "|c=";
    for (size_t i = 0; i < coefficients.size(); ++i) key << (i == 0 ? "" : ",") << Number(coefficients[i]);
  }
  if (coefficients_absolute) key << "|absolute";
  return key.str();
}

}  // namespace avatar
