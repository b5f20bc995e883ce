#pragma once
// The fusion net's input for one frame of the detail path (core/model/fusion_net.h): the layers a
// geometric composite was made of, packed in the net's channel order as bytes. The data factory
// stores exactly these bytes for training and inference converts the same bytes, so the net sees
// one input format.

#include <opencv2/core.hpp>
#include <torch/torch.h>

#include "core/pipeline/detail_layers.h"

namespace avatar {

// uint8 [kFusionInputChannels,H,W]: composite RGB, network render RGB, face-warp weight,
// depth-warp weight, face coverage, eye/mouth region, opacity (0..255 each). Throws InvalidInput
// when a layer is missing or of another size than the frame.
torch::Tensor FusionInputBytes(const DetailLayers& layers);

// The layers the fusion net reads (FusionInputBytes), scaled to `size` by area averaging (masks
// and weights as fractions, images as colours): the input of a frame larger than the side the
// net was trained at. The other fields are left empty. Throws InvalidInput for an empty size or a
// missing layer.
DetailLayers ScaledFusionLayers(const DetailLayers& layers, cv::Size size);

// A BGR8 image as uint8 [3,H,W] RGB.
torch::Tensor RgbBytes(const cv::Mat& bgr);
// A mask (CV_8UC1 0..255, or CV_32FC1 in [0,1]) as uint8 [1,H,W]. Throws InvalidInput.
torch::Tensor MaskBytes(const cv::Mat& mask);
// uint8 [3,H,W] RGB (or float [3,H,W] in [-1,1]) as a BGR8 image.
cv::Mat BgrFromRgb(const torch::Tensor& rgb);

}  // namespace avatar
