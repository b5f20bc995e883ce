// Drivers and the animation plan: keyframe interpolation, relative transfer, smoothing and
// the camera of each export view, checked against hand-computed values.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>

#include "common/temp_dir.h"
#include "core/pipeline/animate.h"
#include "core/pipeline/driving.h"
#include "core/util/error.h"

namespace avatar {
namespace {

using avatar::testing::TempDir;

TEST(Keyframes, InterpolateLinearlyAndHoldTheEnds) {
  KeyframeDriver::Key a, b;
  a.time = 1.0;
  a.pose.yaw = 10;
  a.expression["smile"] = 0.0f;
  b.time = 3.0;
  b.pose.yaw = 30;
  b.pose.zoom = 2.0;
  b.expression["smile"] = 1.0f;
  b.expression["jawOpen"] = 0.5f;
  KeyframeDriver d({b, a}, 10.0, 4.0);  // Unsorted on purpose.
  EXPECT_EQ(d.FrameCount(), 41);
  EXPECT_DOUBLE_EQ(d.At(0.0).pose.yaw, 10.0);  // Before the first key: held.
  EXPECT_DOUBLE_EQ(d.At(2.0).pose.yaw, 20.0);
  EXPECT_DOUBLE_EQ(d.At(2.0).pose.zoom, 1.5);
  EXPECT_FLOAT_EQ(d.At(2.5).expression.Get("smile"), 0.75f);
  EXPECT_FLOAT_EQ(d.At(2.0).expression.Get("jawOpen"), 0.25f);  // Missing in a key = 0.
  EXPECT_DOUBLE_EQ(d.At(3.7).pose.yaw, 30.0);                   // After the last key: held.
  RunContext ctx;
  DrivingSample s;
  int64_t n = 0;
  while (d.Next(s, ctx)) ++n;
  EXPECT_EQ(n, 41);
}

TEST(Keyframes, FileErrorsNameTheFileAndField) {
  TempDir dir;
  std::ofstream(dir / "a.json") << "{\"keys\": []}";
  std::ofstream(dir / "b.json") << "{\"keys\": [{\"time\": 0, \"yaw\": \"left\"}]}";
  std::ofstream(dir / "c.json") << "not json";
  for (const char* name : {"a.json", "b.json", "c.json"}) {
    try {
      KeyframeDriver d(dir / name);
      ADD_FAILURE() << name << " was accepted";
    } catch (const InvalidInput& e) {
      EXPECT_NE(std::string(e.what()).find(name), std::string::npos) << e.what();
    }
  }
  EXPECT_THROW(KeyframeDriver(dir / "missing.json"), Io);
}

TEST(DrivingTransfer, RelativeSubtractsTheNeutralFrame) {
  DrivingOptions o;
  o.smoothing = 0.0;
  DrivingTransfer t(o);
  FrameMeasurement neutral;
  neutral.face_found = true;
  neutral.pose.yaw = 5;
  neutral.coefficients = {1.0f, -1.0f};
  t.SetNeutral(neutral);
  FrameMeasurement m = neutral;
  m.pose.yaw = 12;
  m.coefficients = {1.5f, 0.0f};
  const DrivingSample s = t.Apply(m, true);
  EXPECT_DOUBLE_EQ(s.pose.yaw, 7.0);
  EXPECT_FLOAT_EQ(s.expression.coefficients[0], 0.5f);
  EXPECT_FLOAT_EQ(s.expression.coefficients[1], 1.0f);
  o.relative = false;
  DrivingTransfer absolute(o);
  absolute.SetNeutral(neutral);
  EXPECT_FLOAT_EQ(absolute.Apply(m, true).expression.coefficients[0], 1.5f);
}

TEST(DrivingTransfer, SmoothingIsAnExponentialAverage) {
  DrivingOptions o;
  o.relative = false;
  o.smoothing = 0.5;
  DrivingTransfer t(o);
  FrameMeasurement m;
  m.face_found = true;
  m.coefficients = {0.0f};
  t.Apply(m, true);
  m.coefficients = {1.0f};
  EXPECT_FLOAT_EQ(t.Apply(m, true).expression.coefficients[0], 0.5f);
  EXPECT_FLOAT_EQ(t.Apply(m, true).expression.coefficients[0], 0.75f);
  t.ResetHistory();
  EXPECT_FLOAT_EQ(t.Apply(m, true).expression.coefficients[0], 1.0f);
  // A step input converges to the target and never overshoots.
  DrivingOptions heavy = o;
  heavy.smoothing = 0.9;
  DrivingTransfer h(heavy);
  m.coefficients = {0.0f};
  h.Apply(m, true);
  m.coefficients = {1.0f};
  float prev = 0.0f;
  for (int i = 0; i < 200; ++i) {
    const float v = h.Apply(m, true).expression.coefficients[0];
    EXPECT_GE(v, prev);
    EXPECT_LE(v, 1.0f);
    prev = v;
  }
  EXPECT_NEAR(prev, 1.0f, 1e-6);
}

TEST(DrivingOptions, RejectsBadValues) {
  DrivingOptions o;
  o.smoothing = 1.0;
  EXPECT_THROW(o.Validate(), InvalidOptions);
  o.smoothing = 0.2;
  o.neutral_frame = -1;
  EXPECT_THROW(o.Validate(), InvalidOptions);
}

class PosedSource : public PortraitFrameSource {
 public:
  PosedSource() : PortraitFrameSource(cv::Mat(8, 8, CV_8UC3, cv::Scalar::all(1))) {}
  ViewPose SourcePose() const override { return {4.0, -2.0, 1.0, 1.0}; }
};

TEST(PlanFrame, EachViewModeGivesTheExpectedCamera) {
  PosedSource source;
  AnimationPlan plan;
  plan.base_expression.controls["smile"] = 0.25f;
  DrivingSample sample;
  sample.pose = {10.0, 3.0, 0.0, 1.0};
  sample.expression.controls["smile"] = 0.5f;
  sample.expression.coefficients = {0.1f};

  plan.view.mode = "driver";
  FrameRequest r = PlanFrame(source, plan, &sample, true, 0, 10);
  EXPECT_DOUBLE_EQ(r.view.yaw, 14.0);  // Source pose + the driver's relative pose.
  EXPECT_DOUBLE_EQ(r.view.pitch, 1.0);
  EXPECT_FLOAT_EQ(r.expression.Get("smile"), 0.75f);
  EXPECT_EQ(r.expression.coefficients, std::vector<float>{0.1f});
  r = PlanFrame(source, plan, &sample, false, 0, 10);
  EXPECT_DOUBLE_EQ(r.view.yaw, 10.0);  // Keyframes give the camera directly.

  plan.view.mode = "source";
  r = PlanFrame(source, plan, &sample, true, 3, 10);
  EXPECT_DOUBLE_EQ(r.view.yaw, 4.0);

  plan.view.mode = "orbit";
  plan.view.orbit_degrees = 30.0;
  EXPECT_NEAR(PlanFrame(source, plan, nullptr, false, 0, 8).view.yaw, 4.0, 1e-12);
  EXPECT_NEAR(PlanFrame(source, plan, nullptr, false, 2, 8).view.yaw, 34.0, 1e-12);  // Quarter turn: peak.
  EXPECT_NEAR(PlanFrame(source, plan, nullptr, false, 6, 8).view.yaw, -26.0, 1e-12);
  plan.view.zoom = 2.0;
  EXPECT_DOUBLE_EQ(PlanFrame(source, plan, nullptr, false, 0, 8).view.zoom, 2.0);
  // Controls are clamped to [0,1].
  sample.expression.controls["smile"] = 5.0f;
  EXPECT_FLOAT_EQ(PlanFrame(source, plan, &sample, true, 0, 8).expression.Get("smile"), 1.0f);
}

}  // namespace
}  // namespace avatar
