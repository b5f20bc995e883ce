#pragma once
// Conversions between OpenCV images and the network's NCHW tensors, as the session feeds its
// inputs and reads its outputs (the face networks' NHWC warps are core/face/warp.h).

#include <opencv2/core.hpp>
#include <torch/torch.h>

namespace avatar {

// BGR8 [H,W] -> RGB [1,3,size,size] float32 in [-1,1] (area-resized when the size differs).
// Throws InvalidInput naming `what` for an empty or non-BGR8 image.
torch::Tensor ImageToTensor(const cv::Mat& bgr, int size, const char* what);
// Single-channel mask (8-bit 0..255 or float 0..1) -> [1,1,size,size] float32 in [0,1];
// `fill` everywhere when the mask is empty. Throws InvalidInput (wrong type, non-finite values).
torch::Tensor MaskToTensor(const cv::Mat& mask, int size, float fill, const char* what);
// CV_32FC3 BGR in [0,1] -> [3,H,W] RGB float32 in [-1,1] (no resize).
torch::Tensor FloatBgrToTensor(const cv::Mat& bgr);
// [1,3,H,W] or [3,H,W] RGB (one channel: grey) in [-1,1], or in [0,1] when `unit_range`, on any
// device -> [H,W] CV_8UC3 BGR (clamped, rounded).
cv::Mat TensorToBgr(const torch::Tensor& rgb, bool unit_range = false);
// [1,1,H,W] (or [1,H,W]) on any device -> [size,size] CV_32FC1 (resized bilinearly when H
// differs from `size`; size 0 = H).
cv::Mat TensorToFloatMat(const torch::Tensor& x, int size = 0);

}  // namespace avatar
