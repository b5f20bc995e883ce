#include "core/face/head_pose_net.h"

#include <algorithm>
#include <cmath>
#include <mutex>
#include <vector>

#include <opencv2/dnn.hpp>
#include <opencv2/imgproc.hpp>

#include "core/face/identity_net.h"
#include "core/io/data_paths.h"
#include "core/util/error.h"

namespace avatar::face {
namespace {

// Softmax expectation over the 66 bins of 3 degrees, centred on 0.
float BinExpectation(const float* logits) {
  float hi = logits[0];
  for (int i = 1; i < HeadPoseNet::kBins; ++i) hi = std::max(hi, logits[i]);
  double sum = 0, weighted = 0;
  for (int i = 0; i < HeadPoseNet::kBins; ++i) {
    const double p = std::exp(static_cast<double>(logits[i] - hi));
    sum += p;
    weighted += p * i;
  }
  return static_cast<float>(weighted / sum * 3.0 - 99.0);
}

}  // namespace

struct HeadPoseNet::Impl {
  std::filesystem::path file;
  std::mutex mutex;
  cv::dnn::Net net;
  std::vector<std::string> outputs;
};

HeadPoseNet::HeadPoseNet(const std::string& data_dir)
    : HeadPoseNet(DataPaths::Resolve(data_dir).Path("models/fr_pose.onnx"), 0) {}

std::unique_ptr<HeadPoseNet> HeadPoseNet::FromFile(const std::filesystem::path& onnx) {
  return std::unique_ptr<HeadPoseNet>(new HeadPoseNet(onnx, 0));
}

HeadPoseNet::HeadPoseNet(const std::filesystem::path& onnx, int) : impl_(std::make_unique<Impl>()) {
  impl_->file = onnx;
  impl_->net = LoadOnnxNet(onnx);
  impl_->outputs = impl_->net.getUnconnectedOutLayersNames();
  AVATAR_CHECK_AS(ModelLoad, impl_->outputs.size() == 3)
      << "model " << onnx.string() << " has " << impl_->outputs.size() << " outputs, expected 3 (not fr_pose.onnx?)"
      << kReinstall;
  try {
    RawAngles(cv::Mat(kInputSize, kInputSize, CV_8UC3, cv::Scalar(128, 128, 128)));
  } catch (const cv::Exception& e) {
    throw ModelLoad("model " + onnx.string() + " does not run on a 1x3x224x224 input (" + e.msg + ")" + kReinstall);
  }
}

HeadPoseNet::~HeadPoseNet() = default;

const std::vector<std::string>& HeadPoseNet::OutputNames() const { return impl_->outputs; }

cv::Mat HeadPoseNet::Crop(const cv::Mat& bgr, const cv::Rect2f& box, float box_scale) {
  AVATAR_CHECK_INPUT(!bgr.empty() && bgr.type() == CV_8UC3) << "head pose needs an 8-bit BGR image";
  AVATAR_CHECK_INPUT(box.width > 1 && box.height > 1 && box_scale > 0) << "degenerate face box";
  const double side = std::max(box.width, box.height) * box_scale;
  const double cx = box.x + box.width / 2.0, cy = box.y + box.height / 2.0;
  const double s = kInputSize / side;
  // crop = s * (p - (c - side/2)), pixel centres aligned.
  const cv::Matx23d m(s, 0, -s * (cx - side / 2) + 0.5 * s - 0.5, 0, s, -s * (cy - side / 2) + 0.5 * s - 0.5);
  cv::Mat crop;
  cv::warpAffine(bgr, crop, cv::Mat(m), cv::Size(kInputSize, kInputSize), cv::INTER_AREA, cv::BORDER_REPLICATE);
  return crop;
}

std::array<float, 3> HeadPoseNet::RawAngles(const cv::Mat& crop, Normalisation norm) const {
  AVATAR_CHECK_INPUT(!crop.empty() && crop.type() == CV_8UC3) << "head pose needs an 8-bit BGR crop";
  cv::Mat rgb;
  cv::resize(crop, rgb, cv::Size(kInputSize, kInputSize), 0, 0, cv::INTER_AREA);
  cv::cvtColor(rgb, rgb, cv::COLOR_BGR2RGB);
  cv::Mat f;
  std::array<double, 3> mean{0, 0, 0}, std{1, 1, 1};
  if (norm == Normalisation::kImageNet) {
    mean = {0.485, 0.456, 0.406};
    std = {0.229, 0.224, 0.225};
  } else if (norm == Normalisation::kMinusOneOne) {
    mean = {0.5, 0.5, 0.5};
    std = {0.5, 0.5, 0.5};
  }
  rgb.convertTo(f, CV_32FC3, 1.0 / 255.0);
  f -= cv::Scalar(mean[0], mean[1], mean[2]);
  cv::divide(f, cv::Scalar(std[0], std[1], std[2]), f);
  const cv::Mat blob = cv::dnn::blobFromImage(f);  // NCHW, no further scaling
  std::vector<cv::Mat> outs;
  {
    std::lock_guard<std::mutex> lock(impl_->mutex);
    impl_->net.setInput(blob);
    impl_->net.forward(outs, impl_->outputs);
  }
  std::array<float, 3> angles{};
  for (int k = 0; k < 3; ++k) {
    AVATAR_CHECK_AS(ModelLoad, outs[k].total() == static_cast<size_t>(kBins))
        << "model " << impl_->file.string() << " output " << k << " has " << outs[k].total() << " values, expected "
        << kBins << kReinstall;
    angles[k] = BinExpectation(outs[k].ptr<float>());
  }
  return angles;
}

HeadPose HeadPoseNet::EstimateCrop(const cv::Mat& crop) const {
  const auto a = RawAngles(crop);
  HeadPose p;
  // Output order and signs measured on the packaged photos (see RawAngles).
  p.pitch = a[0];
  p.roll = a[1];
  p.yaw = a[2];
  return p;
}

HeadPose HeadPoseNet::Estimate(const cv::Mat& bgr, const cv::Rect2f& box, float box_scale) const {
  return EstimateCrop(Crop(bgr, box, box_scale));
}

}  // namespace avatar::face
