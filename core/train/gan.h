#pragma once
// Adversarial loss terms of GOHA's second training stage (Li et al. 2023, section 3.4: the
// dual discriminator of EG3D), each a plain function of logits so that it can be tested by
// finite differences in double precision apart from the networks.
//
//   generator:      softplus(-D(fake))                      (non-saturating logistic loss)
//   discriminator:  softplus(D(fake)) + softplus(-D(real))
//   R1:             |grad_x D(x)|^2 at real inputs x, summed over every input tensor of D (for
//                   the dual discriminator: the high-res image and the low-res image), per sample.
// The trainer applies R1 lazily (StyleGAN2): every r1_every steps with weight
// gamma / 2 x r1_every, so that its average weight per step is gamma / 2.
// LibTorch only (no OpenCV).

#include <vector>

#include <torch/torch.h>

namespace avatar::train {

// Non-saturating generator loss per sample: logits [B] or [B,1] -> [B].
torch::Tensor GeneratorGanLoss(const torch::Tensor& fake_logits);
// Discriminator loss per sample: softplus(fake) + softplus(-real) -> [B].
torch::Tensor DiscriminatorGanLoss(const torch::Tensor& real_logits, const torch::Tensor& fake_logits);
// R1 per sample -> [B]: sum over `inputs` (each [B,...], requiring grad, that `real_logits`
// was computed from) of the squared gradient of sum(real_logits). The result is differentiable
// (create_graph), so its gradient reaches D's parameters. Throws InvalidInput when an input
// does not require grad.
torch::Tensor R1Penalty(const torch::Tensor& real_logits, const std::vector<torch::Tensor>& inputs);

}  // namespace avatar::train
