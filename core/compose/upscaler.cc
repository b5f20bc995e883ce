#include "core/compose/upscaler.h"

#include <cstring>
#include <filesystem>

#include <opencv2/imgproc.hpp>
#include <torch/torch.h>

#include "core/io/data_paths.h"
#include "core/io/keras_layers.h"
#include "core/model/keras_net.h"
#include "core/util/error.h"

namespace avatar::compose {

const std::vector<std::string>& UpscalerNames() {
  static const std::vector<std::string> names = {"bicubic", "esrgan-slim"};
  return names;
}

ImageUpscaler::ImageUpscaler(const std::string& name, const std::string& data_dir) : name_(name) {
  if (name == "bicubic") return;
  AVATAR_CHECK_OPTION(name == "esrgan-slim") << "unknown upscaler '" << name << "': choose bicubic or esrgan-slim";
  const std::filesystem::path file = DataPaths::Resolve(data_dir).Path("models/esrgan-slim-x2/model.json");
  if (!std::filesystem::exists(file)) {
    throw MissingData(file.string() + " is missing: the esrgan-slim upscaler comes with the data of scripts/setup "
                      "(data version 3); run scripts/setup");
  }
  net_ = std::make_unique<KerasNet>(io::LoadKerasLayersModel(file));
  if (net_->InputChannels() != 3 || net_->Scale() != 2) {
    throw ModelLoad(file.string() + ": not an x2 RGB upscaler (input channels " +
                    std::to_string(net_->InputChannels()) + ", scale " + std::to_string(net_->Scale()) + ")");
  }
}

ImageUpscaler::~ImageUpscaler() = default;
ImageUpscaler::ImageUpscaler(ImageUpscaler&&) noexcept = default;
ImageUpscaler& ImageUpscaler::operator=(ImageUpscaler&&) noexcept = default;

cv::Mat ImageUpscaler::Upscale(const cv::Mat& bgr, cv::Size size) const {
  AVATAR_CHECK_INPUT(!bgr.empty() && bgr.type() == CV_8UC3 && bgr.cols >= 2 && bgr.rows >= 2)
      << "the upscaler takes a BGR8 image of at least 2 x 2 pixels";
  AVATAR_CHECK_INPUT(size.width >= 1 && size.height >= 1 && size.width <= 16384 && size.height <= 16384)
      << "bad upscale size " << size.width << " x " << size.height;
  cv::Mat out;
  if (!net_) {
    cv::resize(bgr, out, size, 0, 0, cv::INTER_CUBIC);
    return out;
  }
  // The model takes and returns RGB in 0..255 (NHWC in TF.js; NCHW here).
  cv::Mat rgb;
  cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
  torch::NoGradGuard no_grad;
  const torch::Tensor x =
      torch::from_blob(rgb.data, {1, rgb.rows, rgb.cols, 3}, torch::kUInt8).permute({0, 3, 1, 2}).to(torch::kFloat32);
  const torch::Tensor y = net_->Forward(x).clamp(0.0, 255.0).round().to(torch::kUInt8).permute({0, 2, 3, 1}).contiguous();
  cv::Mat up(static_cast<int>(y.size(1)), static_cast<int>(y.size(2)), CV_8UC3);
  std::memcpy(up.data, y.data_ptr<uint8_t>(), static_cast<size_t>(y.numel()));
  cv::cvtColor(up, up, cv::COLOR_RGB2BGR);
  if (up.size() == size) return up;
  cv::resize(up, out, size, 0, 0, size.width < up.cols ? cv::INTER_AREA : cv::INTER_CUBIC);
  return out;
}

double ImageUpscaler::MultiplyAdds(int width, int height) const {
  return net_ ? net_->MultiplyAdds(height, width) : 0.0;
}

}  // namespace avatar::compose
