#include "core/io/image_tensor.h"

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

torch::Tensor FloatBgrToTensor(const cv::Mat& bgr) {
  AVATAR_CHECK_INPUT(!bgr.empty() && bgr.type() == CV_32FC3) << "expected a float BGR image in [0,1]";
  cv::Mat rgb;
  cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
  const torch::Tensor t = torch::from_blob(rgb.data, {rgb.rows, rgb.cols, 3}, torch::kFloat32).clone();
  return t.permute({2, 0, 1}).mul(2.0).sub(1.0).contiguous();  // [3,H,W]
}

cv::Mat TensorToBgr(const torch::Tensor& rgb, bool unit_range) {
  torch::Tensor t = rgb.detach().to(torch::kCPU, torch::kFloat32);
  if (t.dim() == 4) t = t[0];
  if (t.size(0) == 1) t = t.repeat({3, 1, 1});
  t = unit_range ? t.clamp(0.0, 1.0) * 255.0 : (t.clamp(-1.0, 1.0) + 1.0) * 127.5;
  t = t.round().to(torch::kUInt8).permute({1, 2, 0}).contiguous();
  cv::Mat img(static_cast<int>(t.size(0)), static_cast<int>(t.size(1)), CV_8UC3, t.data_ptr());
  cv::Mat bgr;
  cv::cvtColor(img, bgr, cv::COLOR_RGB2BGR);
  return bgr;
}

cv::Mat TensorToFloatMat(const torch::Tensor& x, int size) {
  const torch::Tensor t = x.detach().to(torch::kCPU, torch::kFloat32).reshape({x.size(-2), x.size(-1)}).contiguous();
  cv::Mat m(static_cast<int>(t.size(0)), static_cast<int>(t.size(1)), CV_32FC1, t.data_ptr());
  cv::Mat out;
  if (size > 0 && m.rows != size) {
    cv::resize(m, out, cv::Size(size, size), 0, 0, cv::INTER_LINEAR);
  } else {
    out = m.clone();
  }
  return out;
}

}  // namespace avatar
