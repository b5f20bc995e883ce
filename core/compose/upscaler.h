#pragma once
// The 256 -> 512 step of an export: bicubic resampling, or a learned x2 upscaler of the
// ESRGAN family (@upscalerjs/esrgan-slim's x2 RDN, MIT, installed by scripts/setup as
// models/esrgan-slim-x2/; run by core/model/keras_net.h). `avatar-studio bench upscale` measures
// them against each other on real validation frames (docs/PERFORMANCE.md).

#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace avatar {

class KerasNet;

namespace compose {

// "bicubic", "esrgan-slim".
const std::vector<std::string>& UpscalerNames();

class ImageUpscaler {
 public:
  // Throws InvalidOptions (an unknown name, listing the choices), MissingData (the model is not
  // installed: run scripts/setup), ModelLoad (a damaged model file).
  explicit ImageUpscaler(const std::string& name, const std::string& data_dir = {});
  ~ImageUpscaler();
  ImageUpscaler(ImageUpscaler&&) noexcept;
  ImageUpscaler& operator=(ImageUpscaler&&) noexcept;

  // `bgr` (CV_8UC3, at least 2 x 2) to `size`: a learned upscaler runs at its own factor (x2),
  // then resizes (area) to `size` when that differs; bicubic resizes directly. Throws
  // InvalidInput for an empty or non-BGR8 image or a bad size.
  cv::Mat Upscale(const cv::Mat& bgr, cv::Size size) const;

  const std::string& name() const { return name_; }
  // Multiply-adds of one upscale of a w x h input (0 for bicubic).
  double MultiplyAdds(int width, int height) const;

 private:
  std::string name_;
  std::unique_ptr<KerasNet> net_;
};

}  // namespace compose
}  // namespace avatar
