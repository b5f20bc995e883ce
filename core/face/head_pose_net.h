#pragma once
// Head pose from faceplugin's fr_pose.onnx (ShuffleNetV2, Hopenet-style): a 224x224 crop around
// the face box, three 66-bin classifiers whose softmax expectation gives the angle,
//   angle = 3 * sum_i p_i * i - 99 degrees.
// An estimator independent of our facemesh pose (HeadPoseFromLandmarks), for the APD metric.
// Thread-safe: the cv::dnn::Net is guarded by a mutex.

#include <array>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "core/face/face_types.h"

namespace avatar::face {

class HeadPoseNet {
 public:
  static constexpr int kInputSize = 224;
  static constexpr int kBins = 66;

  // How pixels become network input (kImageNet is what fr_pose expects: see docs/DEVIATIONS.md).
  enum class Normalisation { kImageNet, kMinusOneOne, kZeroOne };

  // Loads models/fr_pose.onnx from the data folder ("" = AVATAR_DATA_DIR, then
  // ~/.cache/avatar-studio). Throws ModelLoad (missing, truncated, foreign or wrong-shaped
  // file), naming the file and scripts/setup.
  explicit HeadPoseNet(const std::string& data_dir = {});
  static std::unique_ptr<HeadPoseNet> FromFile(const std::filesystem::path& onnx);
  ~HeadPoseNet();
  HeadPoseNet(const HeadPoseNet&) = delete;
  HeadPoseNet& operator=(const HeadPoseNet&) = delete;

  // Pose (degrees, HeadPose's sign conventions) of the face in `box` (image pixels) of a BGR8
  // image. The crop is the box's square enlarged by `box_scale`, centred on the box.
  HeadPose Estimate(const cv::Mat& bgr, const cv::Rect2f& box, float box_scale = 1.3f) const;
  // Same, for a crop that is already square (resized to 224).
  HeadPose EstimateCrop(const cv::Mat& crop_bgr) const;

  // The network's output layer names, in the order RawAngles reports them.
  const std::vector<std::string>& OutputNames() const;

  // The three raw angles in the network's output order (as cv::dnn lists the unconnected
  // outputs), no sign change. Measured against facemesh on the packaged photos: output 0 is
  // pitch, 1 roll, 2 yaw, each with our HeadPose signs (docs/DEVIATIONS.md).
  std::array<float, 3> RawAngles(const cv::Mat& crop_bgr, Normalisation norm = Normalisation::kImageNet) const;

  // Square crop of side `box_scale` * max(box side) around the box centre, 224x224 BGR8.
  static cv::Mat Crop(const cv::Mat& bgr, const cv::Rect2f& box, float box_scale);

 private:
  struct Impl;
  explicit HeadPoseNet(const std::filesystem::path& onnx, int);
  std::unique_ptr<Impl> impl_;
};

}  // namespace avatar::face
