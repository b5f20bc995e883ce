// ProgressLine: redrawn in place on a terminal, one line per interval in logs.
#include "core/util/progress_line.h"

#include <unistd.h>

#include <gtest/gtest.h>

#include <iostream>
#include <sstream>

namespace avatar {
namespace {

TEST(ProgressLine, TerminalRedrawsInPlaceAndClearsALongerLine) {
  std::ostringstream out;
  ProgressLine line(out, true);
  line.Update("step 1/9 loss 0.25");
  line.Update("step 2/9");
  line.Finish();
  line.Finish();  // A second Finish writes nothing.
  EXPECT_EQ(out.str(), "\rstep 1/9 loss 0.25\rstep 2/9          \n");
}

TEST(ProgressLine, LogWritesTheFirstUpdateThenOnePerIntervalAndTheLastOnFinish) {
  std::ostringstream out;
  ProgressLine line(out, false, 3600.0);
  line.Update("a");
  line.Update("b");
  line.Update("c");
  EXPECT_EQ(out.str(), "a\n");  // b and c fall inside the interval.
  line.Finish();
  EXPECT_EQ(out.str(), "a\nc\n");
  line.Finish();
  EXPECT_EQ(out.str(), "a\nc\n");
  EXPECT_EQ(out.str().find('\r'), std::string::npos);
}

TEST(ProgressLine, LogWithAZeroIntervalWritesEveryUpdateOnce) {
  std::ostringstream out;
  ProgressLine line(out, false, 0.0);
  line.Update("a");
  line.Update("b");
  line.Finish();  // b was written already.
  EXPECT_EQ(out.str(), "a\nb\n");
}

TEST(ProgressLine, ForStderrFollowsWhetherStderrIsATerminal) {
  std::ostringstream captured;
  std::streambuf* const saved = std::cerr.rdbuf(captured.rdbuf());
  {
    ProgressLine line = ProgressLine::ForStderr(0.0);
    line.Update("x");
    line.Finish();
  }
  std::cerr.rdbuf(saved);
  EXPECT_EQ(captured.str(), ::isatty(STDERR_FILENO) == 1 ? "\rx\n" : "x\n");
}

}  // namespace
}  // namespace avatar
