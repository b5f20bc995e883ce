#include "core/util/run_context.h"

#include <gtest/gtest.h>

#include <thread>
#include <vector>

#include "core/util/error.h"

namespace avatar {
namespace {

TEST(RunContext, CancelFromAnotherThreadStopsTheNextCheck) {
  RunContext ctx;
  EXPECT_NO_THROW(ctx.ThrowIfCancelled());
  std::thread other([&] { ctx.RequestCancel(); });
  other.join();
  EXPECT_TRUE(ctx.IsCancelled());
  EXPECT_THROW(ctx.ThrowIfCancelled(), Cancelled);
  EXPECT_THROW(ctx.Report("stage", 0.5), Cancelled);
}

TEST(RunContext, ProgressRangesNestAndRestore) {
  std::vector<Progress> seen;
  RunContext ctx([&](const Progress& p) { seen.push_back(p); });
  ctx.Report("a", 0.0);
  {
    RunContext::ProgressRange outer(ctx, 0.5, 1.0);
    ctx.Report("b", 0.5);  // -> 0.75
    {
      RunContext::ProgressRange inner(ctx, 0.0, 0.5);  // [0.5, 0.75]
      ctx.Report("c", 1.0);                           // -> 0.75
      ctx.Report("c", 0.0);                           // -> 0.5
    }
    ctx.Report("d", 2.0);  // clamped -> 1.0
  }
  ctx.Report("e", 0.25);  // range restored -> 0.25
  ASSERT_EQ(seen.size(), 6u);
  EXPECT_DOUBLE_EQ(seen[1].fraction, 0.75);
  EXPECT_DOUBLE_EQ(seen[2].fraction, 0.75);
  EXPECT_DOUBLE_EQ(seen[3].fraction, 0.5);
  EXPECT_DOUBLE_EQ(seen[4].fraction, 1.0);
  EXPECT_DOUBLE_EQ(seen[5].fraction, 0.25);
  EXPECT_EQ(ctx.Last().stage, "e");
}

}  // namespace
}  // namespace avatar
