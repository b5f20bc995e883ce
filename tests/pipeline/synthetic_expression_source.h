#pragma once
// A synthetic I_exp renderer for pipeline tests: a grey face disk whose mouth opens with
// jawOpen and curves with smile. It stands in for the morphable model's frontal render (its
// loader is registered in every test that includes this header, so avatar files with it load).
// Also what the session tests reconstruct with: the tiny random-weight session, the frontal
// camera label and the frontal SourceFit.

#include <array>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "core/pipeline/session.h"
#include "core/render/camera.h"
#include "core/util/error.h"

namespace avatar::testing {

class SyntheticExpressionSource : public ExpressionImageSource {
 public:
  explicit SyntheticExpressionSource(int shade = 180) : shade_(shade) {}
  cv::Mat Render(const Expression& expression, int size) const override {
    float jaw = 0.0f, smile = 0.0f;
    for (const auto& [name, value] : expression.controls) {
      if (name == "jawOpen")
        jaw = value;
      else if (name == "smile")
        smile = value;
      else
        throw InvalidInput("unknown expression control '" + name + "' (jawOpen, smile)");
    }
    cv::Mat img = cv::Mat::zeros(size, size, CV_8UC3);
    const cv::Point c(size / 2, size / 2);
    cv::circle(img, c, size * 3 / 8, cv::Scalar(shade_, shade_, shade_ + 20), cv::FILLED);
    const int mw = size / 6, mh = std::max(1, static_cast<int>(size / 40 + jaw * size / 8));
    cv::ellipse(img, cv::Point(c.x, c.y + size / 6 - static_cast<int>(smile * size / 20)), cv::Size(mw, mh), 0, 0, 360,
                cv::Scalar(30, 30, 120), cv::FILLED);
    return img;
  }
  std::vector<std::string> ControlNames() const override { return {"jawOpen", "smile"}; }
  std::string Kind() const override { return "test-synthetic"; }
  std::string Serialize() const override { return std::to_string(shade_); }

  static std::shared_ptr<const ExpressionImageSource> Load(const std::string& bytes) {
    return std::make_shared<SyntheticExpressionSource>(std::stoi(bytes));
  }

 private:
  int shade_;
};

inline const bool kSyntheticSourceLoaderRegistered =
    RegisterExpressionSourceLoader("test-synthetic", &SyntheticExpressionSource::Load);

// The tiny network with random weights drawn with `seed`.
inline SessionOptions TinySessionOptions(int seed) {
  SessionOptions o;
  o.random_weights = true;
  o.config = "tiny";
  o.seed = seed;
  return o;
}

// The frontal camera C_front (default intrinsics) as an EG3D label.
inline std::array<float, 25> FrontalCameraLabel() {
  const torch::Tensor label = render::LabelsFromCameras(render::FrontalCameras(1))[0];
  std::array<float, 25> out{};
  for (int i = 0; i < 25; ++i) out[i] = label[i].item<float>();
  return out;
}

// A source fit at C_front whose I_exp comes from `expressions` (by default the synthetic source).
inline SourceFit FrontalFit(
    std::shared_ptr<const ExpressionImageSource> expressions = std::make_shared<SyntheticExpressionSource>()) {
  SourceFit fit;
  fit.camera = FrontalCameraLabel();
  fit.expressions = std::move(expressions);
  return fit;
}

}  // namespace avatar::testing
