#include "core/util/options.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <sstream>

namespace avatar {
namespace options {
namespace {

std::string Lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}

std::string FieldName(const std::string& flag) {
  std::string out = flag;
  std::replace(out.begin(), out.end(), '-', '_');
  return out;
}

}  // namespace

std::string FlagName(const std::string& field) {
  std::string out = field;
  std::replace(out.begin(), out.end(), '_', '-');
  return out;
}

void ParseValue(const std::string& flag, const std::string& text, bool& out) {
  const std::string v = Lower(text);
  if (v == "1" || v == "true" || v == "yes" || v == "on") {
    out = true;
  } else if (v == "0" || v == "false" || v == "no" || v == "off") {
    out = false;
  } else {
    throw InvalidOptions(flag + " expects true or false, got '" + text + "'");
  }
}

void ParseValue(const std::string& flag, const std::string& text, int64_t& out) {
  errno = 0;
  char* end = nullptr;
  const long long v = std::strtoll(text.c_str(), &end, 10);
  AVATAR_CHECK_OPTION(!text.empty() && end != nullptr && *end == '\0' && errno == 0)
      << flag << " expects an integer, got '" << text << "'";
  out = static_cast<int64_t>(v);
}

void ParseValue(const std::string& flag, const std::string& text, int& out) {
  int64_t v = 0;
  ParseValue(flag, text, v);
  AVATAR_CHECK_OPTION(v >= INT32_MIN && v <= INT32_MAX) << flag << " is out of range: " << text;
  out = static_cast<int>(v);
}

void ParseValue(const std::string& flag, const std::string& text, double& out) {
  errno = 0;
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  AVATAR_CHECK_OPTION(!text.empty() && end != nullptr && *end == '\0' && errno == 0 && std::isfinite(v))
      << flag << " expects a finite number, got '" << text << "'";
  out = v;
}

void ParseValue(const std::string& flag, const std::string& text, float& out) {
  double v = 0;
  ParseValue(flag, text, v);
  out = static_cast<float>(v);
}

void ParseValue(const std::string& /*flag*/, const std::string& text, std::string& out) { out = text; }

void ParseValue(const std::string& /*flag*/, const std::string& text, std::vector<std::string>& out) {
  out.push_back(text);
}

std::string FormatValue(bool v) { return v ? "true" : "false"; }
std::string FormatValue(int v) { return std::to_string(v); }
std::string FormatValue(int64_t v) { return std::to_string(v); }
std::string FormatValue(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}
std::string FormatValue(float v) { return FormatValue(static_cast<double>(v)); }
std::string FormatValue(const std::string& v) { return v; }
std::string FormatValue(const std::vector<std::string>& v) {
  std::string out;
  for (const auto& s : v) out += (out.empty() ? "" : ",") + s;
  return out;
}

namespace detail {

void Tokenise(const std::vector<std::string>& args, const std::vector<std::string>& bool_fields,
              const std::vector<char>& bool_aliases, std::vector<PendingFlag>* flags,
              std::vector<std::string>* positionals) {
  auto is_bool = [&](const std::string& field) {
    return std::find(bool_fields.begin(), bool_fields.end(), field) != bool_fields.end();
  };
  bool only_positionals = false;
  for (size_t i = 0; i < args.size(); ++i) {
    const std::string& a = args[i];
    if (only_positionals || a.size() < 2 || a[0] != '-' || (a[1] != '-' && std::isdigit(static_cast<unsigned char>(a[1])))) {
      positionals->push_back(a);
      continue;
    }
    if (a == "--") {
      only_positionals = true;
      continue;
    }
    PendingFlag f;
    if (a[1] != '-') {
      // Short alias: -o VALUE or -o=VALUE (single letter only).
      f.alias = a[1];
      if (a.size() > 2) {
        AVATAR_CHECK_OPTION(a[2] == '=') << "unknown option " << a << "; see --help";
        f.has_value = true;
        f.value = a.substr(3);
      } else if (std::find(bool_aliases.begin(), bool_aliases.end(), f.alias) == bool_aliases.end()) {
        AVATAR_CHECK_OPTION(i + 1 < args.size()) << a << " needs a value";
        f.has_value = true;
        f.value = args[++i];
      }
      flags->push_back(f);
      continue;
    }
    std::string body = a.substr(2);
    const size_t eq = body.find('=');
    if (eq != std::string::npos) {
      f.has_value = true;
      f.value = body.substr(eq + 1);
      body = body.substr(0, eq);
    }
    f.name = FieldName(body);
    if (!is_bool(f.name) && f.name.rfind("no_", 0) == 0 && is_bool(f.name.substr(3))) {
      f.name = f.name.substr(3);
      f.negated = true;
    }
    if (!f.has_value && !is_bool(f.name)) {
      // Value-taking flag: the next argument is its value (even if it starts with '-').
      AVATAR_CHECK_OPTION(i + 1 < args.size()) << "--" << body << " needs a value";
      f.has_value = true;
      f.value = args[++i];
    }
    flags->push_back(f);
  }
}

}  // namespace detail
}  // namespace options
}  // namespace avatar
