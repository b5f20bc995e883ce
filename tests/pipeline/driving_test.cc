// Drivers and the animation plan: keyframe interpolation, relative transfer, smoothing, the
// camera of each export view, and the one seekable video driver (DrivingVideo: hold on a
// missed face, the neutral-frame rule, seeking = playback), checked against hand-computed
// values on clips written here whose frames encode what a stand-in analyser "measures".
#include <gtest/gtest.h>

#include <opencv2/videoio.hpp>

#include <cmath>
#include <fstream>
#include <map>
#include <random>

#include "common/temp_dir.h"
#include "core/pipeline/animate.h"
#include "core/pipeline/driving.h"
#include "core/util/error.h"

namespace avatar {
namespace {

using avatar::testing::TempDir;
namespace fs = std::filesystem;

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
  // Per driver frame: after 3 frames (2 dropped) the previous sample weighs 0.5^3, as three
  // single steps towards a constant input would leave it.
  t.ResetHistory();
  m.coefficients = {0.0f};
  t.Apply(m, true);
  m.coefficients = {1.0f};
  EXPECT_FLOAT_EQ(t.Apply(m, true, 3).expression.coefficients[0], 1.0f - 0.125f);
  EXPECT_THROW(t.Apply(m, true, 0), InvalidInput);
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

// ----------------------------------------------------------------------------- DrivingVideo

// Frame k of a test clip is flat grey 40 + 20 * level, or black (level < 0: "no face").
fs::path WriteClip(const TempDir& dir, const std::string& name, const std::vector<int>& levels, double fps = 10.0) {
  const fs::path path = dir / name;
  cv::VideoWriter writer(path.string(), cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), fps, cv::Size(32, 32));
  EXPECT_TRUE(writer.isOpened()) << "OpenCV cannot write MJPG";
  for (int level : levels) writer.write(cv::Mat(32, 32, CV_8UC3, cv::Scalar::all(level < 0 ? 0 : 40 + 20 * level)));
  writer.release();
  return path;
}

// "Measures" the grey level: yaw = 2 * level, pitch = -level, coefficients {level, -level};
// a black frame has no face. Counts its calls when given a counter.
class LevelAnalyzer : public FrameAnalyzer {
 public:
  explicit LevelAnalyzer(int* calls = nullptr) : calls_(calls) {}
  FrameMeasurement Measure(const cv::Mat& bgr, RunContext&) override {
    if (calls_ != nullptr) ++*calls_;
    FrameMeasurement m;
    const double grey = cv::mean(bgr)[0];
    if (grey < 20.0) return m;
    const int level = static_cast<int>(std::lround((grey - 40.0) / 20.0));
    m.face_found = true;
    m.pose.yaw = 2.0 * level;
    m.pose.pitch = -level;
    m.coefficients = {static_cast<float>(level), static_cast<float>(-level)};
    return m;
  }

 private:
  int* calls_;
};

DrivingOptions Unsmoothed() {
  DrivingOptions o;
  o.smoothing = 0.0;
  return o;
}

TEST(DrivingVideo, MissedFacesHoldTheLastFaceSeen) {
  TempDir dir;
  //                                       0  1   2   3  4   5
  const fs::path clip = WriteClip(dir, "c.avi", {1, 2, -1, -1, 5, -1});
  RunContext ctx;
  DrivingVideo v(clip, std::make_unique<LevelAnalyzer>(), Unsmoothed(), ctx);
  EXPECT_EQ(v.FrameCount(), 6);
  EXPECT_EQ(v.NeutralFrame(), 0);
  EXPECT_TRUE(v.NeutralNote().empty());
  const std::vector<double> yaw = {0, 2, 2, 2, 8, 8};  // Relative to frame 0 (level 1).
  const std::vector<bool> face = {true, true, false, false, true, false};
  for (int64_t i = 0; i < 6; ++i) {
    DrivingSample s;
    ASSERT_TRUE(v.At(i, s, ctx));
    EXPECT_DOUBLE_EQ(s.pose.yaw, yaw[i]) << "frame " << i;
    EXPECT_DOUBLE_EQ(s.pose.pitch, -yaw[i] / 2) << "frame " << i;
    ASSERT_EQ(s.expression.coefficients.size(), 2u);
    EXPECT_FLOAT_EQ(s.expression.coefficients[0], static_cast<float>(yaw[i] / 2)) << "frame " << i;
    EXPECT_EQ(s.face_found, face[i]) << "frame " << i;
  }
  DrivingSample s;
  EXPECT_FALSE(v.At(6, s, ctx));  // Past the end.
  EXPECT_FALSE(v.At(-1, s, ctx));
}

TEST(DrivingVideo, SeekingGivesWhatPlaybackGives) {
  TempDir dir;
  std::vector<int> levels;
  for (int i = 0; i < 60; ++i) levels.push_back((i % 7 == 3 || (i >= 30 && i < 38)) ? -1 : i % 9);
  const fs::path clip = WriteClip(dir, "long.avi", levels);
  RunContext ctx;
  DrivingVideo played(clip, std::make_unique<LevelAnalyzer>(), Unsmoothed(), ctx);
  std::vector<DrivingSample> expected(levels.size());
  for (size_t i = 0; i < levels.size(); ++i) ASSERT_TRUE(played.At(static_cast<int64_t>(i), expected[i], ctx));
  // A fresh driver visited in random order (scrubbing) gives every frame the same sample,
  // a held one included (the nearest earlier face is looked up).
  DrivingVideo scrubbed(clip, std::make_unique<LevelAnalyzer>(), Unsmoothed(), ctx);
  std::vector<int64_t> order(levels.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = static_cast<int64_t>(i);
  std::shuffle(order.begin(), order.end(), std::mt19937(7));
  int held = 0;
  for (int64_t i : order) {
    DrivingSample s;
    ASSERT_TRUE(scrubbed.At(i, s, ctx));
    EXPECT_EQ(s.pose, expected[i].pose) << "frame " << i;
    EXPECT_EQ(s.expression, expected[i].expression) << "frame " << i;
    EXPECT_EQ(s.face_found, expected[i].face_found) << "frame " << i;
    held += s.face_found ? 0 : 1;
  }
  EXPECT_EQ(held, 16);  // 8 frames with i % 7 == 3 outside 30..37, plus 30..37.
  EXPECT_DOUBLE_EQ(expected[37].pose.yaw, expected[29].pose.yaw);  // 29 is the last face before the gap.
}

TEST(DrivingVideo, TheExportDriverIsTheSameDriverPlayedForward) {
  TempDir dir;
  const fs::path clip = WriteClip(dir, "c.avi", {2, 3, -1, 6, -1, -1, 1, 8, 4});
  DrivingOptions o;
  o.smoothing = 0.4;
  o.neutral_frame = 1;
  RunContext ctx;
  VideoDriver exported(clip, std::make_unique<LevelAnalyzer>(), o, ctx);
  DrivingVideo preview(clip, std::make_unique<LevelAnalyzer>(), o, ctx);
  DrivingSample a, b;
  int64_t n = 0;
  while (exported.Next(a, ctx)) {
    ASSERT_TRUE(preview.At(n, b, ctx));
    EXPECT_EQ(a.pose, b.pose) << "frame " << n;
    EXPECT_EQ(a.expression, b.expression) << "frame " << n;
    EXPECT_EQ(a.face_found, b.face_found) << "frame " << n;
    ++n;
  }
  EXPECT_EQ(n, 9);
  // Smoothing is on: frame 3 (level 6, neutral level 3) is on its way from the held 0 to 6.
  DrivingVideo again(clip, std::make_unique<LevelAnalyzer>(), o, ctx);
  for (int64_t i = 0; i <= 3; ++i) ASSERT_TRUE(again.At(i, b, ctx));
  EXPECT_GT(b.pose.yaw, 0.0);
  EXPECT_LT(b.pose.yaw, 6.0);
  // A jump restarts the smoothing: frame 3 alone is the raw offset.
  ASSERT_TRUE(again.At(7, b, ctx));
  ASSERT_TRUE(again.At(3, b, ctx));
  EXPECT_DOUBLE_EQ(b.pose.yaw, 6.0);
}

TEST(DrivingVideo, ANeutralFrameWithoutAFaceBecomesTheFirstFrameWithOne) {
  TempDir dir;
  const fs::path clip = WriteClip(dir, "lead.avi", {-1, -1, -1, 3, 4, -1, 6});
  RunContext ctx;
  DrivingVideo v(clip, std::make_unique<LevelAnalyzer>(), Unsmoothed(), ctx);
  EXPECT_EQ(v.NeutralFrame(), 3);
  EXPECT_NE(v.NeutralNote().find("neutral frame 0"), std::string::npos) << v.NeutralNote();
  EXPECT_NE(v.NeutralNote().find("using frame 3 (0.30 s)"), std::string::npos) << v.NeutralNote();
  EXPECT_NE(v.NeutralNote().find("lead.avi"), std::string::npos) << v.NeutralNote();
  DrivingSample s;
  ASSERT_TRUE(v.At(0, s, ctx));  // Before the first face: the neutral frame is held.
  EXPECT_FALSE(s.face_found);
  EXPECT_DOUBLE_EQ(s.pose.yaw, 0.0);
  EXPECT_EQ(s.expression.coefficients, (std::vector<float>{0.0f, 0.0f}));
  ASSERT_TRUE(v.At(4, s, ctx));
  EXPECT_DOUBLE_EQ(s.pose.yaw, 2.0);
  ASSERT_TRUE(v.At(5, s, ctx));
  EXPECT_DOUBLE_EQ(s.pose.yaw, 2.0);  // Held.
  // A requested frame with a face is used as it is, without a note.
  DrivingOptions o = Unsmoothed();
  o.neutral_frame = 6;
  v.SetOptions(o, ctx);
  EXPECT_EQ(v.NeutralFrame(), 6);
  EXPECT_TRUE(v.NeutralNote().empty());
  ASSERT_TRUE(v.At(3, s, ctx));
  EXPECT_DOUBLE_EQ(s.pose.yaw, -6.0);
  // Absolute mode has no neutral frame; leading frames hold the first face.
  o.relative = false;
  v.SetOptions(o, ctx);
  EXPECT_EQ(v.NeutralFrame(), -1);
  ASSERT_TRUE(v.At(1, s, ctx));
  EXPECT_DOUBLE_EQ(s.pose.yaw, 6.0);
  EXPECT_TRUE(s.expression.coefficients_absolute);
  // The export reports the same choice.
  VideoDriver exported(clip, std::make_unique<LevelAnalyzer>(), Unsmoothed(), ctx);
  EXPECT_EQ(exported.Video().NeutralFrame(), 3);
  DrivingVideo fresh(clip, std::make_unique<LevelAnalyzer>(), Unsmoothed(), ctx);
  EXPECT_EQ(exported.Video().NeutralNote(), fresh.NeutralNote());
}

TEST(DrivingVideo, OutOfRangeOrFacelessNeutralFramesAreRefusedClearly) {
  TempDir dir;
  const fs::path clip = WriteClip(dir, "short.avi", {1, 2, 3});
  const fs::path blank = WriteClip(dir, "blank.avi", {-1, -1, -1, -1});
  RunContext ctx;
  DrivingOptions o = Unsmoothed();
  o.neutral_frame = 3;
  for (int pass = 0; pass < 2; ++pass) {
    try {
      if (pass == 0) DrivingVideo refused(clip, std::make_unique<LevelAnalyzer>(), o, ctx);
      if (pass == 1) VideoDriver refused(clip, std::make_unique<LevelAnalyzer>(), o, ctx);
      ADD_FAILURE() << "neutral frame 3 of 3 frames was accepted";
    } catch (const InvalidOptions& e) {
      EXPECT_NE(std::string(e.what()).find("--neutral-frame 3 is past the end"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("0..2"), std::string::npos) << e.what();
    }
  }
  // Changing the options of a loaded driver to an invalid frame keeps the old options.
  DrivingVideo v(clip, std::make_unique<LevelAnalyzer>(), Unsmoothed(), ctx);
  EXPECT_THROW(v.SetOptions(o, ctx), InvalidOptions);
  EXPECT_EQ(v.NeutralFrame(), 0);
  DrivingSample s;
  ASSERT_TRUE(v.At(2, s, ctx));
  EXPECT_DOUBLE_EQ(s.pose.yaw, 4.0);
  // No face anywhere: relative transfer is impossible and says so; absolute runs neutral.
  try {
    DrivingVideo refused(blank, std::make_unique<LevelAnalyzer>(), Unsmoothed(), ctx);
    ADD_FAILURE() << "a clip without a face was accepted for relative transfer";
  } catch (const InvalidInput& e) {
    EXPECT_NE(std::string(e.what()).find("no face found in"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("blank.avi"), std::string::npos) << e.what();
  }
  DrivingOptions absolute = Unsmoothed();
  absolute.relative = false;
  DrivingVideo a(blank, std::make_unique<LevelAnalyzer>(), absolute, ctx);
  ASSERT_TRUE(a.At(1, s, ctx));
  EXPECT_FALSE(s.face_found);
  EXPECT_TRUE(s.expression.coefficients.empty());
  // Without an analyser the video gives timing only, whatever the neutral frame.
  DrivingVideo timing(clip, nullptr, o, ctx);
  EXPECT_FALSE(timing.Measured());
  ASSERT_TRUE(timing.At(1, s, ctx));
  EXPECT_TRUE(s.expression.coefficients.empty());
}

TEST(DrivingVideo, EachFrameIsMeasuredOnce) {
  TempDir dir;
  const fs::path clip = WriteClip(dir, "c.avi", {1, -1, 3, 4, -1, -1, 7, 8});
  int calls = 0;
  RunContext ctx;
  DrivingVideo v(clip, std::make_unique<LevelAnalyzer>(&calls), Unsmoothed(), ctx);
  DrivingSample s;
  for (int round = 0; round < 3; ++round) {
    for (int64_t i : {5, 2, 0, 7, 1, 3, 4, 6}) {
      cv::Mat picture;
      ASSERT_TRUE(v.At(i, s, ctx, &picture));
      EXPECT_EQ(picture.size(), cv::Size(32, 32));
    }
  }
  EXPECT_EQ(calls, 8);
}

TEST(Compose, TheViewIsTheSourcePoseTurnedByTheUserAndTheDriver) {
  const ViewPose source{4.0, -2.0, 1.0, 1.0};
  const ViewPose user{10.0, 5.0, -3.0, 1.5};
  const ViewPose driver{-1.0, 2.0, 0.5, 1.0};
  ViewPose v = ComposeView(source, user, &driver);
  EXPECT_DOUBLE_EQ(v.yaw, 13.0);
  EXPECT_DOUBLE_EQ(v.pitch, 5.0);
  EXPECT_DOUBLE_EQ(v.roll, -1.5);
  EXPECT_DOUBLE_EQ(v.zoom, 1.5);
  v = ComposeView(source, user, nullptr);
  EXPECT_DOUBLE_EQ(v.yaw, 14.0);
  EXPECT_DOUBLE_EQ(v.roll, -2.0);
  // The user's controls plus the driver's, clamped; the driver's coefficients.
  FrameExpression mine;
  mine.controls["smile"] = 0.75f;
  DrivingSample s;
  s.pose = driver;
  s.expression.controls["smile"] = 0.5f;
  s.expression.controls["jawOpen"] = -0.5f;
  s.expression.coefficients = {0.25f, -0.5f};
  s.expression.coefficients_absolute = true;
  const FrameRequest r = ComposeFrame(source, user, mine, &s, true, 48, 32);
  EXPECT_EQ(r.width, 48);
  EXPECT_EQ(r.height, 32);
  EXPECT_DOUBLE_EQ(r.view.yaw, 13.0);
  EXPECT_FLOAT_EQ(r.expression.Get("smile"), 1.0f);
  EXPECT_FLOAT_EQ(r.expression.Get("jawOpen"), 0.0f);
  EXPECT_EQ(r.expression.coefficients, s.expression.coefficients);
  EXPECT_TRUE(r.expression.coefficients_absolute);
  EXPECT_DOUBLE_EQ(ComposeFrame(source, user, mine, &s, false, 48, 32).view.yaw, 14.0);  // Pose not followed.
  EXPECT_TRUE(ComposeFrame(source, user, mine, nullptr, true, 48, 32).expression.coefficients.empty());
}

}  // namespace
}  // namespace avatar
