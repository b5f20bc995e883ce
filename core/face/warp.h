#pragma once
// Conversions between OpenCV images and the NHWC float tensors the face networks take.

#include <opencv2/core.hpp>
#include <torch/torch.h>

namespace avatar::face {

// Warps `bgr` (CV_8UC3) with the affine `image_to_out` into an out_w x out_h RGB tensor
// [1,out_h,out_w,3] float32 with values mapped from [0,255] to [lo,hi]. Pixels outside the
// image are black (lo). Strong downscaling is pre-filtered (area resize) to avoid aliasing.
torch::Tensor WarpToTensor(const cv::Mat& bgr, const cv::Matx23d& image_to_out, int out_w, int out_h, float lo, float hi);

// Warps `bgr` with `image_to_out` into an out_w x out_h BGR image (black outside), pre-filtering
// strong downscaling like WarpToTensor.
cv::Mat WarpImage(const cv::Mat& bgr, const cv::Matx23d& image_to_out, int out_w, int out_h);

// Inverse of a 2x3 affine transform.
cv::Matx23d InvertAffine(const cv::Matx23d& m);
// Applies a 2x3 affine transform to a point.
cv::Point2f ApplyAffine(const cv::Matx23d& m, const cv::Point2f& p);
// Uniform scale factor of a similarity transform (sqrt of |det|).
double AffineScale(const cv::Matx23d& m);

}  // namespace avatar::face
