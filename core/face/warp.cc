#include "core/face/warp.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>

#include "core/util/error.h"

namespace avatar::face {

cv::Matx23d InvertAffine(const cv::Matx23d& m) {
  cv::Matx23d inv;
  cv::invertAffineTransform(m, inv);
  return inv;
}

cv::Point2f ApplyAffine(const cv::Matx23d& m, const cv::Point2f& p) {
  return {static_cast<float>(m(0, 0) * p.x + m(0, 1) * p.y + m(0, 2)),
          static_cast<float>(m(1, 0) * p.x + m(1, 1) * p.y + m(1, 2))};
}

double AffineScale(const cv::Matx23d& m) { return std::sqrt(std::abs(m(0, 0) * m(1, 1) - m(0, 1) * m(1, 0))); }

cv::Mat WarpImage(const cv::Mat& bgr, const cv::Matx23d& image_to_out, int out_w, int out_h) {
  AVATAR_CHECK_INPUT(!bgr.empty() && bgr.type() == CV_8UC3) << "expected a non-empty 8-bit BGR image";
  cv::Matx23d m = image_to_out;
  cv::Mat src = bgr;
  const double scale = AffineScale(m);
  if (scale < 0.5 && scale > 0.0) {
    // Area-resize first so the bilinear warp samples a band-limited image.
    const double pre = std::min(1.0, 2.0 * scale);
    cv::Mat small;
    const cv::Size dsize(std::max(1, cvRound(bgr.cols * pre)), std::max(1, cvRound(bgr.rows * pre)));
    cv::resize(bgr, small, dsize, 0, 0, cv::INTER_AREA);
    const double sx = static_cast<double>(small.cols) / bgr.cols;
    const double sy = static_cast<double>(small.rows) / bgr.rows;
    // Area resize maps pixel centres: small = (orig + 0.5) * s - 0.5, so
    // orig = (small + 0.5) / s - 0.5; fold that into the matrix.
    const double tx = 0.5 / sx - 0.5, ty = 0.5 / sy - 0.5;
    m = cv::Matx23d(m(0, 0) / sx, m(0, 1) / sy, m(0, 2) + m(0, 0) * tx + m(0, 1) * ty,  //
                    m(1, 0) / sx, m(1, 1) / sy, m(1, 2) + m(1, 0) * tx + m(1, 1) * ty);
    src = small;
  }
  cv::Mat out;
  cv::warpAffine(src, out, m, cv::Size(out_w, out_h), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar::all(0));
  return out;
}

torch::Tensor WarpToTensor(const cv::Mat& bgr, const cv::Matx23d& image_to_out, int out_w, int out_h, float lo, float hi) {
  cv::Mat warped = WarpImage(bgr, image_to_out, out_w, out_h);
  cv::Mat rgb;
  cv::cvtColor(warped, rgb, cv::COLOR_BGR2RGB);
  cv::Mat f;
  rgb.convertTo(f, CV_32FC3, (hi - lo) / 255.0, lo);
  // [1,H,W,3] float32 in [lo,hi], RGB.
  return torch::from_blob(f.data, {1, out_h, out_w, 3}, torch::kFloat32).clone();
}

}  // namespace avatar::face
