#pragma once
// Loss terms of GOHA's first training stage (Li et al. 2023, section 3.4), each a plain
// function of tensors so that it can be tested (analytically and by finite differences in
// double precision) apart from the network.
//
// Images are [B,C,H,W] in [-1,1]; masks [B,1,H,W] in [0,1]. Every image loss returns one value
// per sample ([B]); the trainer averages over the batch and applies the weights.
// LibTorch only (no OpenCV): this builds against CPU and CUDA LibTorch alike.

#include <cstdint>
#include <functional>

#include <torch/torch.h>

namespace avatar::train {

// A perceptual distance between two image batches [B,3,H,W] in [-1,1] -> [B]. The real one
// (MobileNetV2 features) lives in core/train/perceptual.h; tests use PyramidL1Distance.
using PerceptualFn = std::function<torch::Tensor(const torch::Tensor& a, const torch::Tensor& b)>;

// Mean absolute difference per sample -> [B]. With `mask` ([B,1,H,W], broadcast over channels)
// the mean runs over the masked pixels only: sum(m |a-b|) / (C sum(m) + 1e-8).
torch::Tensor L1Distance(const torch::Tensor& a, const torch::Tensor& b, const torch::Tensor& mask = {});

// A parameter-free stand-in for a perceptual distance: the mean over `levels` scales (the image,
// then 2x2 average pools of it) of the per-sample L1 distance. Smooth, cheap, deterministic.
torch::Tensor PyramidL1Distance(const torch::Tensor& a, const torch::Tensor& b, int levels = 3);

// L1 + perceptual_weight * perceptual(a, b) per sample -> [B]. `perceptual` may be empty (L1 only).
torch::Tensor ImageLoss(const torch::Tensor& a, const torch::Tensor& b, const PerceptualFn& perceptual,
                        double perceptual_weight = 1.0);

// Composites an image over the black (-1) background with a mask: x m + (-1)(1 - m).
torch::Tensor Matte(const torch::Tensor& image, const torch::Tensor& mask);

// Resizes images/masks [B,C,S,S] to `size`: box averaging when S is a multiple of size (no
// aliasing), bilinear otherwise. Returns the input when it already has that size.
torch::Tensor ResizeTo(const torch::Tensor& x, int64_t size);

// The neutral ("cano") loss: the canonical render at the source camera I_c [B,3,R,R] against the
// morphable model's neutral image I_neu [B,3,S,S], both matted by the coverage M_neu [B,1,S,S]
// of the morphable face (I_neu and M_neu are resized to R first): ImageLoss of the two matted
// images -> [B]. The trainer weights it by TrainerOptions::neutral_weight (3, as the release).
torch::Tensor NeutralLoss(const torch::Tensor& canonical_rgb, const torch::Tensor& neutral_image,
                          const torch::Tensor& neutral_mask, const PerceptualFn& perceptual,
                          double perceptual_weight = 1.0);

// A raw-density function: world points [B,P,3] -> raw sigma [B,P] (before softplus).
using DensityFn = std::function<torch::Tensor(const torch::Tensor& points)>;

// Total variation of the density at given point pairs: mean |sigma(p) - sigma(p')| over every
// point of every sample -> scalar. points and perturbed are [B,P,3] world coordinates.
torch::Tensor DensityTvAt(const DensityFn& density, const torch::Tensor& points, const torch::Tensor& perturbed);

// Options of the random TV loss.
struct TvOptions {
  // Points per sample (release: 1000).
  int64_t num_points = 1000;
  // Std of the perturbation in normalised plane coordinates ([-1,1] over the box; release: 0.004).
  double sigma = 0.004;
  // Side of the box the tri-planes span (world units; RenderOptions::box_warp).
  double box_warp = 1.0;
};

// The TV loss on densities: num_points uniform points in the planes' box [-box/2, box/2]^3
// (normalised [-1,1]^3), each perturbed by N(0, sigma) in normalised units (sigma * box/2 in
// world units); DensityTvAt of the pairs. The release draws its points in world [-1,1]^3, which
// for box_warp 1 puts 7/8 of them outside the planes (zero features, no signal); we draw inside
// the box. Uses the global generator of `options`' device (checkpointed with the trainer).
torch::Tensor DensityTvLoss(const DensityFn& density, int64_t batch, const TvOptions& options,
                            const torch::TensorOptions& tensor_options = torch::kFloat32);

// Peak signal-to-noise ratio in dB of images in [-1,1] (mapped to [0,1]) -> scalar double.
double Psnr(const torch::Tensor& a, const torch::Tensor& b);

}  // namespace avatar::train
