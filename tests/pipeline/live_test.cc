// Live driving (core/pipeline/live.h) without a camera: the grabber on a video file played as a
// camera (paced, newest frame wins, ends), and RunLive on a scripted camera and analyser: the
// automatic neutral reference, a frame without a face holds the last pose and says so, the face
// coming back, a resolution change restarting the tracker, a camera that stalls; a missing
// camera is a clear error.
#include <gtest/gtest.h>

#include <chrono>
#include <deque>
#include <thread>

#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "common/temp_dir.h"
#include "core/pipeline/live.h"
#include "core/util/error.h"

namespace avatar {
namespace {

// Frame k of the test videos: grey level 8k (the index is read back from the pixels).
cv::Mat NumberedFrame(int k, cv::Size size) { return cv::Mat(size, CV_8UC3, cv::Scalar::all(8 * k + 4)); }
int NumberOf(const cv::Mat& bgr) { return static_cast<int>(std::lround((cv::mean(bgr)[0] - 4.0) / 8.0)); }

// A frame source that records the requests it renders.
class RecordingSource : public FrameSource {
 public:
  std::string Label() const override { return "recording"; }
  bool SupportsPose() const override { return true; }
  std::vector<std::string> ExpressionControls() const override { return {}; }
  int CoefficientCount() const override { return 2; }
  RenderedFrame Render(const FrameRequest& request, RunContext&) const override {
    requests.push_back(request);
    if (render_ms > 0) std::this_thread::sleep_for(std::chrono::milliseconds(render_ms));
    RenderedFrame f;
    f.bgr = cv::Mat(request.height, request.width, CV_8UC3, cv::Scalar(1, 2, 3));
    f.alpha = cv::Mat(request.height, request.width, CV_8UC1, cv::Scalar(255));
    return f;
  }
  mutable std::vector<FrameRequest> requests;
  int render_ms = 0;
};

// Measures the frame number: a face on every frame except those listed, yaw = 2 x number and
// the first coefficient = number / 10.
class NumberAnalyzer : public FrameAnalyzer {
 public:
  explicit NumberAnalyzer(std::vector<int> no_face = {}) : no_face_(std::move(no_face)) {}
  FrameMeasurement Measure(const cv::Mat& bgr, RunContext&) override {
    const int k = NumberOf(bgr);
    FrameMeasurement m;
    m.face_found = std::find(no_face_.begin(), no_face_.end(), k) == no_face_.end();
    m.pose.yaw = 2.0 * k;
    m.coefficients = {static_cast<float>(k) / 10.0f, 0.0f};
    return m;
  }
  void Reset() override { ++resets; }
  int resets = 0;

 private:
  std::vector<int> no_face_;
};

// Delivers scripted frames at once, then stalls (or ends).
class ScriptedCamera : public LiveCamera {
 public:
  ScriptedCamera(std::vector<cv::Mat> frames, bool end) : end_(end) {
    for (auto& f : frames) frames_.push_back(std::move(f));
  }
  bool Take(CameraFrame* frame, double timeout_seconds) override {
    if (frames_.empty()) {
      if (!end_) std::this_thread::sleep_for(std::chrono::duration<double>(timeout_seconds));
      return false;
    }
    frame->bgr = frames_.front();
    frame->index = index_++;
    frame->captured = LiveClock::now();
    frames_.pop_front();
    return true;
  }
  bool Ended() const override { return end_ && frames_.empty(); }
  std::string Error() const override { return {}; }
  int64_t Captured() const override { return index_; }
  int64_t Dropped() const override { return 0; }
  double Fps() const override { return 25.0; }

 private:
  std::deque<cv::Mat> frames_;
  bool end_;
  int64_t index_ = 0;
};

TEST(Live, AVideoFilePlaysAsACameraAndTheNewestFrameWins) {
  testing::TempDir dir;
  const std::string video = (dir / "camera.avi").string();
  {
    cv::VideoWriter writer(video, cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), 25.0, cv::Size(64, 48));
    ASSERT_TRUE(writer.isOpened());
    for (int k = 0; k < 25; ++k) writer.write(NumberedFrame(k, cv::Size(64, 48)));
  }
  CameraGrabber camera(video);
  EXPECT_TRUE(camera.IsFile());
  EXPECT_NEAR(camera.Fps(), 25.0, 0.01);
  // A consumer four times slower than the camera: it sees every fourth frame or so, in order,
  // and the others are dropped, not queued.
  const auto start = LiveClock::now();
  std::vector<int64_t> taken;
  CameraFrame frame;
  while (camera.Take(&frame, 2.0)) {
    EXPECT_EQ(NumberOf(frame.bgr), frame.index);
    taken.push_back(frame.index);
    std::this_thread::sleep_for(std::chrono::milliseconds(160));
  }
  const double seconds = std::chrono::duration<double>(LiveClock::now() - start).count();
  EXPECT_TRUE(camera.Ended());
  EXPECT_EQ(camera.Error(), "");
  EXPECT_EQ(camera.Captured(), 25);
  EXPECT_EQ(camera.Dropped() + static_cast<int64_t>(taken.size()), 25);
  EXPECT_GT(camera.Dropped(), 10);
  for (size_t i = 1; i < taken.size(); ++i) EXPECT_GT(taken[i], taken[i - 1]);
  EXPECT_GT(seconds, 0.9) << "25 frames at 25 fps were not paced as a camera";
}

TEST(Live, NoCameraIsAClearError) {
  try {
    CameraGrabber camera("63");
    FAIL() << "camera 63 opened";
  } catch (const InvalidInput& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("no camera /dev/video63"), std::string::npos) << what;
    EXPECT_NE(what.find("--camera"), std::string::npos) << what;
  }
  testing::TempDir dir;
  EXPECT_THROW(CameraGrabber((dir / "none.mp4").string()), InvalidInput);
  LiveOptions bad;
  bad.stall_seconds = 0.0;
  EXPECT_THROW(bad.Validate(), InvalidOptions);
}

TEST(Live, NoFaceHoldsTheLastPoseAndTheFaceComesBack) {
  std::vector<cv::Mat> frames;
  for (int k = 0; k < 8; ++k) frames.push_back(NumberedFrame(k, cv::Size(64, 48)));
  for (int k = 8; k < 10; ++k) frames.push_back(NumberedFrame(k, cv::Size(80, 60)));  // a new resolution
  ScriptedCamera camera(frames, true);
  NumberAnalyzer analyzer({0, 3, 4});
  RecordingSource source;
  LiveOptions options;
  options.width = options.height = 32;
  options.driving.smoothing = 0.0;
  std::vector<LiveFrameInfo> infos;
  RunContext ctx;
  const LiveStats stats = RunLive(source, analyzer, camera, options,
                                  [&](const RenderedFrame& f, const LiveFrameInfo& info) {
                                    EXPECT_EQ(f.bgr.size(), cv::Size(32, 32));
                                    infos.push_back(info);
                                  },
                                  ctx);
  ASSERT_EQ(infos.size(), 10u);
  EXPECT_EQ(stats.delivered, 10);
  EXPECT_EQ(stats.no_face, 3);
  EXPECT_EQ(stats.ended, "the video ended");
  // Frame 0: no face yet, the portrait's own pose; frame 1 is the neutral reference.
  EXPECT_FALSE(infos[0].face_found);
  EXPECT_NE(infos[0].note.find("No face in the camera frame yet"), std::string::npos) << infos[0].note;
  EXPECT_NE(infos[1].note.find("Neutral reference: camera frame 1"), std::string::npos) << infos[1].note;
  EXPECT_NEAR(infos[1].sample.pose.yaw, 0.0, 1e-6);
  EXPECT_NEAR(infos[2].sample.pose.yaw, 2.0, 1e-6);  // relative to frame 1
  // Frames 3 and 4: held at frame 2's pose, said once.
  EXPECT_NE(infos[3].note.find("holding the last pose"), std::string::npos) << infos[3].note;
  EXPECT_EQ(infos[4].note, "");
  EXPECT_NEAR(infos[3].sample.pose.yaw, 2.0, 1e-6);
  EXPECT_NEAR(infos[4].sample.pose.yaw, 2.0, 1e-6);
  EXPECT_NE(infos[5].note.find("The face is back"), std::string::npos) << infos[5].note;
  EXPECT_NEAR(infos[5].sample.pose.yaw, 8.0, 1e-6);
  // The resolution change restarts the tracker and is told.
  EXPECT_NE(infos[8].note.find("changed its resolution from 64x48 to 80x60"), std::string::npos) << infos[8].note;
  EXPECT_EQ(analyzer.resets, 1);
  for (const auto& info : infos) {
    EXPECT_GE(info.latency_ms, 0.0);
    EXPECT_TRUE(std::isfinite(info.latency_ms));
  }
  EXPECT_EQ(source.requests.size(), 10u);
}

TEST(Live, ACameraThatStallsEndsTheSessionWithTheReason) {
  ScriptedCamera camera({NumberedFrame(1, cv::Size(64, 48)), NumberedFrame(2, cv::Size(64, 48))}, false);
  NumberAnalyzer analyzer;
  RecordingSource source;
  LiveOptions options;
  options.width = options.height = 32;
  options.stall_seconds = 0.2;
  RunContext ctx;
  int frames = 0;
  const LiveStats stats =
      RunLive(source, analyzer, camera, options, [&](const RenderedFrame&, const LiveFrameInfo&) { ++frames; }, ctx);
  EXPECT_EQ(frames, 2);
  EXPECT_NE(stats.ended.find("no frame for"), std::string::npos) << stats.ended;
  EXPECT_GT(stats.latency_median_ms, -1e-9);
}

}  // namespace
}  // namespace avatar
