#include "core/util/logging.h"

#include <gtest/gtest.h>

#include <vector>

namespace avatar {
namespace {

TEST(Logging, SinkReceivesLinesAtOrAboveTheLevel) {
  std::vector<std::pair<LogLevel, std::string>> lines;
  LogSink previous = SetLogSink([&](LogLevel l, const std::string& m) { lines.emplace_back(l, m); });
  const LogLevel saved = GetLogLevel();
  SetLogLevel(LogLevel::kInfo);
  int side_effects = 0;
  AVATAR_LOG(kDebug) << "hidden " << ++side_effects;
  AVATAR_LOG(kInfo) << "shown " << 42;
  AVATAR_LOG(kError) << "bad";
  SetLogLevel(saved);
  SetLogSink(previous);
  ASSERT_EQ(lines.size(), 2u);
  EXPECT_EQ(lines[0].second, "shown 42");
  EXPECT_EQ(lines[1].first, LogLevel::kError);
  EXPECT_EQ(side_effects, 0);  // Filtered lines do not evaluate their arguments.
  EXPECT_STREQ(LogLevelName(LogLevel::kWarning), "warning");
}

}  // namespace
}  // namespace avatar
