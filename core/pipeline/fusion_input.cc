#include "core/pipeline/fusion_input.h"

#include <opencv2/imgproc.hpp>

#include "core/model/fusion_net.h"
#include "core/util/error.h"

namespace avatar {

torch::Tensor RgbBytes(const cv::Mat& bgr) {
  AVATAR_CHECK_INPUT(!bgr.empty() && bgr.type() == CV_8UC3) << "fusion input: an image must be BGR8";
  cv::Mat rgb;
  cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
  return torch::from_blob(rgb.data, {rgb.rows, rgb.cols, 3}, torch::kUInt8).permute({2, 0, 1}).clone();
}

torch::Tensor MaskBytes(const cv::Mat& mask) {
  AVATAR_CHECK_INPUT(!mask.empty() && (mask.type() == CV_8UC1 || mask.type() == CV_32FC1))
      << "fusion input: a mask must be CV_8UC1 or CV_32FC1";
  cv::Mat bytes;
  if (mask.type() == CV_32FC1) {
    cv::Mat clean = mask.clone();
    cv::patchNaNs(clean, 0.0);
    clean = cv::min(cv::max(clean, 0.0), 1.0);
    clean.convertTo(bytes, CV_8UC1, 255.0);
  } else {
    bytes = mask.isContinuous() ? mask : mask.clone();
  }
  return torch::from_blob(bytes.data, {1, bytes.rows, bytes.cols}, torch::kUInt8).clone();
}

cv::Mat BgrFromRgb(const torch::Tensor& rgb) {
  AVATAR_CHECK_INPUT(rgb.defined() && rgb.dim() == 3 && rgb.size(0) == 3) << "fusion output must be [3,H,W]";
  torch::Tensor bytes = rgb;
  if (rgb.scalar_type() != torch::kUInt8) {
    bytes = ((rgb.detach().to(torch::kCPU, torch::kFloat32).nan_to_num(0.0) + 1.0) * 127.5).round().clamp(0, 255)
                .to(torch::kUInt8);
  }
  bytes = bytes.to(torch::kCPU).permute({1, 2, 0}).contiguous();
  cv::Mat rgb_mat(static_cast<int>(bytes.size(0)), static_cast<int>(bytes.size(1)), CV_8UC3, bytes.data_ptr());
  cv::Mat bgr;
  cv::cvtColor(rgb_mat, bgr, cv::COLOR_RGB2BGR);
  return bgr;
}

DetailLayers ScaledFusionLayers(const DetailLayers& layers, cv::Size size) {
  AVATAR_CHECK_INPUT(size.width >= 1 && size.height >= 1) << "fusion input: an empty size to scale the layers to";
  auto scaled = [&](const cv::Mat& m, const char* what) {
    AVATAR_CHECK_INPUT(!m.empty()) << "fusion input: the " << what << " layer is missing";
    cv::Mat out;
    cv::resize(m, out, size, 0, 0, cv::INTER_AREA);
    return out;
  };
  DetailLayers out;
  out.frame.bgr = scaled(layers.frame.bgr, "composite");
  out.frame.alpha = scaled(layers.frame.alpha, "opacity");
  out.network = scaled(layers.network, "network");
  out.face_weight = scaled(layers.face_weight, "face weight");
  out.depth_weight = scaled(layers.depth_weight, "depth weight");
  out.face = scaled(layers.face, "face");
  if (!layers.eye_mouth.empty()) out.eye_mouth = scaled(layers.eye_mouth, "eye/mouth");
  return out;
}

torch::Tensor FusionInputBytes(const DetailLayers& layers) {
  const cv::Size size = layers.frame.bgr.size();
  auto check = [&](const cv::Mat& m, const char* what) {
    AVATAR_CHECK_INPUT(!m.empty() && m.size() == size)
        << "fusion input: the " << what << " layer is missing or not " << size.width << "x" << size.height;
  };
  check(layers.frame.bgr, "composite");
  check(layers.network, "network");
  check(layers.face_weight, "face weight");
  check(layers.depth_weight, "depth weight");
  check(layers.face, "face");
  check(layers.frame.alpha, "opacity");
  const cv::Mat eye_mouth = layers.eye_mouth.empty() ? cv::Mat::zeros(size, CV_8UC1) : layers.eye_mouth;
  check(eye_mouth, "eye/mouth");
  torch::Tensor out = torch::cat({RgbBytes(layers.frame.bgr), RgbBytes(layers.network), MaskBytes(layers.face_weight),
                                  MaskBytes(layers.depth_weight), MaskBytes(layers.face), MaskBytes(eye_mouth),
                                  MaskBytes(layers.frame.alpha)},
                                 0);
  AVATAR_CHECK_INPUT(out.size(0) == kFusionInputChannels) << "fusion input: channel count drifted from the net's";
  return out;
}

}  // namespace avatar
