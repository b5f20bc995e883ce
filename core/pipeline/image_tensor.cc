#include "core/pipeline/image_tensor.h"

#include <opencv2/imgproc.hpp>

#include "core/util/error.h"

namespace avatar {

torch::Tensor ImageToTensor(const cv::Mat& bgr, int size, const char* what) {
  AVATAR_CHECK_INPUT(!bgr.empty() && bgr.type() == CV_8UC3) << what << " must be a non-empty 8-bit BGR image";
  cv::Mat resized;
  if (bgr.rows != size || bgr.cols != size) {
    cv::resize(bgr, resized, cv::Size(size, size), 0, 0, cv::INTER_AREA);
  } else {
    resized = bgr;
  }
  cv::Mat rgb;
  cv::cvtColor(resized, rgb, cv::COLOR_BGR2RGB);
  torch::Tensor t = torch::from_blob(rgb.data, {size, size, 3}, torch::kUInt8).clone();
  return t.permute({2, 0, 1}).unsqueeze(0).to(torch::kFloat32).div(127.5).sub(1.0);  // [1,3,S,S]
}

torch::Tensor MaskToTensor(const cv::Mat& mask, int size, float fill, const char* what) {
  if (mask.empty()) return torch::full({1, 1, size, size}, fill);
  AVATAR_CHECK_INPUT(mask.channels() == 1 && (mask.depth() == CV_8U || mask.depth() == CV_32F))
      << what << " must be a single-channel 8-bit or float image";
  cv::Mat f;
  mask.convertTo(f, CV_32F, mask.depth() == CV_8U ? 1.0 / 255.0 : 1.0);
  cv::resize(f, f, cv::Size(size, size), 0, 0, cv::INTER_AREA);
  torch::Tensor t = torch::from_blob(f.data, {1, 1, size, size}, torch::kFloat32).clone();
  AVATAR_CHECK_INPUT(torch::isfinite(t).all().item<bool>()) << what << " has non-finite values";
  return t.clamp(0.0, 1.0);
}

cv::Mat TensorToBgr(const torch::Tensor& rgb) {
  torch::Tensor t = ((rgb[0].clamp(-1.0, 1.0) + 1.0) * 127.5).round().to(torch::kUInt8).permute({1, 2, 0}).contiguous();
  cv::Mat img(static_cast<int>(t.size(0)), static_cast<int>(t.size(1)), CV_8UC3, t.data_ptr());
  cv::Mat bgr;
  cv::cvtColor(img, bgr, cv::COLOR_RGB2BGR);
  return bgr;
}

cv::Mat TensorToFloatMat(const torch::Tensor& x, int size) {
  torch::Tensor t = x[0][0].to(torch::kFloat32).contiguous();
  cv::Mat m(static_cast<int>(t.size(0)), static_cast<int>(t.size(1)), CV_32FC1, t.data_ptr());
  cv::Mat out;
  if (m.rows != size) {
    cv::resize(m, out, cv::Size(size, size), 0, 0, cv::INTER_LINEAR);
  } else {
    out = m.clone();
  }
  return out;
}

}  // namespace avatar
