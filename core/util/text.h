#pragma once
// Plain-text helpers for tables and flags.

#include <string>
#include <vector>

namespace avatar {

// `value` with exactly `digits` decimals ("%.*f"), for the tables; "n/a" for NaN, "inf" / "-inf".
std::string Fixed(double value, int digits);
// Fixed(value, digits), or "-" for a non-finite value (a table cell with nothing measured).
std::string FixedOrDash(double value, int digits);

// "a,b,,c" -> {"a", "b", "c"} (empty items dropped): comma lists of flags.
std::vector<std::string> SplitList(const std::string& text);

}  // namespace avatar
