#pragma once
// Image quality metrics of evaluation, batched: one value per image. Images are [B,3,H,W] RGB in
// [-1,1]; an optional mask [B,1,H,W] in [0,1] restricts (weights) the pixels that count.
// The face metrics (CSIM from the identity embedding, APD from the head-pose network, AED from
// our morphable fit) need OpenCV and live with the face code; this header is LibTorch only.

#include <functional>

#include <torch/torch.h>

namespace avatar::train {

// Peak signal-to-noise ratio in dB with the peak = the full [-1,1] range (the same figure as
// 8-bit PSNR with peak 255). [B]; identical images give +inf.
torch::Tensor PsnrPerImage(const torch::Tensor& a, const torch::Tensor& b, const torch::Tensor& mask = {});

// Structural similarity (Wang et al. 2004) on [0,1] intensities: 11x11 Gaussian window with
// sigma 1.5, C1 = 0.01^2, C2 = 0.03^2, per channel over the windows that lie fully inside the
// image ("valid"), averaged over channels; with a mask, windows are weighted by the mask at
// their centre. [B]; images smaller than 11x11 throw InvalidInput.
torch::Tensor SsimPerImage(const torch::Tensor& a, const torch::Tensor& b, const torch::Tensor& mask = {});

// Every image metric of one comparison, [B] each.
struct ImageMetrics {
  torch::Tensor psnr, ssim, l1, perceptual;  // perceptual undefined when no distance is given
};
ImageMetrics ComputeImageMetrics(
    const torch::Tensor& a, const torch::Tensor& b, const torch::Tensor& mask = {},
    const std::function<torch::Tensor(const torch::Tensor&, const torch::Tensor&, const torch::Tensor&)>&
        perceptual = {});

}  // namespace avatar::train
