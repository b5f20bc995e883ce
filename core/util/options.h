#pragma once
// The option-struct pattern. An options struct is an aggregate with a // comment and a
// default on every field, plus
//
//   template <typename V> void Visit(V&& v) {
//     v("threads", threads, "LibTorch intra-op threads (0 = all cores)");
//     v("output", output, "Output file", 'o');   // optional one-letter alias
//   }
//   void Validate() const;   // throws InvalidOptions
//
// One visitor serves CLI flags (--threads 2, --threads=2, -o x, --flag / --no-flag),
// JSON load/save and generated help text. Field names use snake_case; flags use dashes.
// Supported field types: bool, int, int64_t, float, double, std::string,
// std::vector<std::string> (a repeatable flag; each occurrence appends).

#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <type_traits>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/util/error.h"

namespace avatar {
namespace options {

// Field codecs (defined in options.cc). `flag` names the option in error messages.
void ParseValue(const std::string& flag, const std::string& text, bool& out);
void ParseValue(const std::string& flag, const std::string& text, int& out);
void ParseValue(const std::string& flag, const std::string& text, int64_t& out);
void ParseValue(const std::string& flag, const std::string& text, float& out);
void ParseValue(const std::string& flag, const std::string& text, double& out);
void ParseValue(const std::string& flag, const std::string& text, std::string& out);
void ParseValue(const std::string& flag, const std::string& text, std::vector<std::string>& out);
std::string FormatValue(bool v);
std::string FormatValue(int v);
std::string FormatValue(int64_t v);
std::string FormatValue(float v);
std::string FormatValue(double v);
std::string FormatValue(const std::string& v);
std::string FormatValue(const std::vector<std::string>& v);

// "data_dir" -> "data-dir".
std::string FlagName(const std::string& field);

namespace detail {

struct HelpRow {
  std::string flag;
  char alias = 0;
  std::string help;
  std::string default_value;
  bool is_bool = false;
};

// One parsed command-line token awaiting a field.
struct PendingFlag {
  std::string name;      // Field-style name (dashes turned into underscores).
  char alias = 0;        // Set when given as -x.
  bool has_value = false;
  std::string value;
  bool negated = false;  // --no-name
};

// Splits argv-style arguments into flags and positionals. Needs to know which flags are
// boolean (they take no separate value) so it receives the names of bool fields.
void Tokenise(const std::vector<std::string>& args, const std::vector<std::string>& bool_fields,
              const std::vector<char>& bool_aliases, std::vector<PendingFlag>* flags,
              std::vector<std::string>* positionals);

template <typename T>
constexpr bool IsBool() {
  return std::is_same<T, bool>::value;
}

// std::vector of numbers (not bool): FromJson checks each element like a number field.
template <typename T>
struct IsNumberList : std::false_type {};
template <typename E, typename A>
struct IsNumberList<std::vector<E, A>> : std::bool_constant<std::is_arithmetic_v<E> && !std::is_same_v<E, bool>> {};

}  // namespace detail

// Writes every field into a JSON object.
template <typename Options>
nlohmann::json ToJson(Options opts) {
  nlohmann::json j = nlohmann::json::object();
  opts.Visit([&](const char* name, auto& field, const char* /*help*/, char /*alias*/ = 0) { j[name] = field; });
  return j;
}

// Reads fields present in `j`; unknown keys or wrong types throw InvalidOptions naming the key.
template <typename Options>
void FromJson(Options& opts, const nlohmann::json& j) {
  AVATAR_CHECK_OPTION(j.is_object()) << "options must be a JSON object";
  std::vector<std::string> known;
  opts.Visit([&](const char* name, auto& field, const char* /*help*/, char /*alias*/ = 0) {
    known.emplace_back(name);
    auto it = j.find(name);
    if (it == j.end()) return;
    using T = std::decay_t<decltype(field)>;
    // nlohmann converts true to 1 and 64.5 to 64 silently, and a number beyond the field's range
    // is undefined behaviour (found by tests/fuzz, target model_config, in a list of ints); a
    // config file means what it says.
    auto check_number = [&](const nlohmann::json& v, auto type) {
      using N = decltype(type);
      AVATAR_CHECK_OPTION(v.is_number()) << "option '" << name << "' must be a number in JSON, got " << v.dump();
      const double d = v.get<double>();
      if constexpr (std::is_integral_v<N>) {
        AVATAR_CHECK_OPTION(std::isfinite(d) && d == std::floor(d) &&
                            d >= static_cast<double>(std::numeric_limits<N>::min()) &&
                            d <= static_cast<double>(std::numeric_limits<N>::max()))
            << "option '" << name << "' must be a whole number in JSON, got " << v.dump();
      } else {
        AVATAR_CHECK_OPTION(!std::isfinite(d) || std::abs(d) <= static_cast<double>(std::numeric_limits<N>::max()))
            << "option '" << name << "' is out of range in JSON, got " << v.dump();
      }
    };
    if constexpr (std::is_arithmetic_v<T> && !std::is_same_v<T, bool>) {
      check_number(*it, T{});
    } else if constexpr (detail::IsNumberList<T>::value) {
      if (it->is_array()) {
        for (const auto& v : *it) check_number(v, typename T::value_type{});
      }
    }
    try {
      it->get_to(field);
    } catch (const nlohmann::json::exception& e) {
      throw InvalidOptions(std::string("option '") + name + "' has the wrong type in JSON: " + e.what());
    }
  });
  for (auto it = j.begin(); it != j.end(); ++it) {
    bool found = false;
    for (const auto& k : known) found = found || k == it.key();
    AVATAR_CHECK_OPTION(found) << "unknown option '" << it.key() << "' in JSON";
  }
}

// Parses flags into `opts` and returns the positional arguments. Unknown flags, missing
// values and malformed numbers throw InvalidOptions naming the flag. Does not Validate().
template <typename Options>
std::vector<std::string> ParseFlags(Options& opts, const std::vector<std::string>& args) {
  std::vector<std::string> bool_fields;
  std::vector<char> bool_aliases;
  opts.Visit([&](const char* name, auto& field, const char* /*help*/, char alias = 0) {
    if (detail::IsBool<std::decay_t<decltype(field)>>()) {
      bool_fields.emplace_back(name);
      if (alias != 0) bool_aliases.push_back(alias);
    }
  });
  std::vector<detail::PendingFlag> flags;
  std::vector<std::string> positionals;
  detail::Tokenise(args, bool_fields, bool_aliases, &flags, &positionals);
  for (const auto& flag : flags) {
    bool consumed = false;
    opts.Visit([&](const char* name, auto& field, const char* /*help*/, char alias = 0) {
      if (consumed) return;
      const bool match = flag.alias != 0 ? flag.alias == alias : flag.name == name;
      if (!match) return;
      consumed = true;
      const std::string shown = flag.alias != 0 ? std::string("-") + flag.alias : "--" + FlagName(name);
      using Field = std::decay_t<decltype(field)>;
      if constexpr (std::is_same<Field, bool>::value) {
        if (flag.has_value) {
          ParseValue(shown, flag.value, field);
          if (flag.negated) field = !field;
        } else {
          field = !flag.negated;
        }
      } else {
        AVATAR_CHECK_OPTION(!flag.negated) << shown << " is not a yes/no flag";
        AVATAR_CHECK_OPTION(flag.has_value) << shown << " needs a value";
        ParseValue(shown, flag.value, field);
      }
    });
    AVATAR_CHECK_OPTION(consumed) << "unknown option "
                                  << (flag.alias != 0 ? std::string("-") + flag.alias : "--" + FlagName(flag.name))
                                  << "; see --help";
  }
  return positionals;
}

// Help text: one line per field with its flag, alias, default and comment.
template <typename Options>
std::string Help(Options opts) {
  std::vector<detail::HelpRow> rows;
  opts.Visit([&](const char* name, auto& field, const char* help, char alias = 0) {
    detail::HelpRow row;
    row.flag = FlagName(name);
    row.alias = alias;
    row.help = help;
    row.default_value = FormatValue(field);
    row.is_bool = detail::IsBool<std::decay_t<decltype(field)>>();
    rows.push_back(row);
  });
  std::string text;
  for (const auto& r : rows) {
    std::string left = "  ";
    left += r.alias != 0 ? std::string("-") + r.alias + ", " : "    ";
    left += "--" + r.flag + (r.is_bool ? "" : " VALUE");
    if (left.size() < 34) left.resize(34, ' ');
    text += left + " " + r.help;
    if (!r.default_value.empty()) text += " [default: " + r.default_value + "]";
    text += "\n";
  }
  return text;
}

}  // namespace options
}  // namespace avatar
