#include "core/pipeline/probe.h"

#include <algorithm>
#include <utility>

#include <opencv2/imgproc.hpp>
#include <torch/torch.h>

#include "core/pipeline/session.h"
#include "core/render/camera.h"
#include "core/util/error.h"

namespace avatar {

FixedExpressionSource::FixedExpressionSource(cv::Mat bgr, std::vector<float> beta, std::string kind,
                                             bool own_expression_only)
    : bgr_(std::move(bgr)), beta_(std::move(beta)), kind_(std::move(kind)), own_expression_only_(own_expression_only) {
  AVATAR_CHECK_INPUT(!bgr_.empty() && bgr_.type() == CV_8UC3) << "a stand-in I_exp must be a BGR8 image";
}

void FixedExpressionSource::Check(const Expression& expression) const {
  AVATAR_CHECK_INPUT(!own_expression_only_ || (expression.controls.empty() && expression.coefficients.empty()))
      << "this stand-in (" << kind_ << ") renders the portrait's own expression only";
}

cv::Mat FixedExpressionSource::Render(const Expression& expression, int size) const {
  Check(expression);
  cv::Mat out;
  cv::resize(bgr_, out, cv::Size(size, size), 0, 0, size < bgr_.cols ? cv::INTER_AREA : cv::INTER_CUBIC);
  return out;
}

std::vector<float> FixedExpressionSource::Coefficients(const Expression& expression) const {
  Check(expression);
  return beta_;
}

cv::Mat ProbePortraitImage() {
  cv::Mat img = cv::Mat::zeros(512, 512, CV_8UC3);
  cv::ellipse(img, cv::Point(256, 270), cv::Size(150, 190), 0, 0, 360, cv::Scalar(120, 150, 200), cv::FILLED);
  cv::circle(img, cv::Point(200, 230), 18, cv::Scalar(40, 40, 40), cv::FILLED);
  cv::circle(img, cv::Point(312, 230), 18, cv::Scalar(40, 40, 40), cv::FILLED);
  cv::ellipse(img, cv::Point(256, 360), cv::Size(60, 18), 0, 0, 360, cv::Scalar(60, 60, 170), cv::FILLED);
  return img;
}

face::AlignedPortrait ProbePortrait() { return PortraitFromAlignedImage(ProbePortraitImage()); }

SourceFit ProbeFit(int expression_coefficients) {
  SourceFit fit;
  fit.expressions = std::make_shared<FixedExpressionSource>(
      ProbePortraitImage(), std::vector<float>(std::max(0, expression_coefficients), 0.0f), "probe", false);
  torch::InferenceMode inference;
  const torch::Tensor label = render::LabelsFromCameras(render::FrontalCameras(1)).reshape({25}).contiguous();
  std::copy(label.data_ptr<float>(), label.data_ptr<float>() + 25, fit.camera.begin());
  return fit;
}

}  // namespace avatar
