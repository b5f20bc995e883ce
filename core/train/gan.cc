#include "core/train/gan.h"

#include "core/util/error.h"

namespace avatar::train {

namespace {

torch::Tensor PerSample(const torch::Tensor& logits) {
  AVATAR_CHECK_INPUT(logits.dim() >= 1 && logits.size(0) >= 1) << "GAN loss: logits must be [B] or [B,1]";
  return logits.reshape({logits.size(0), -1}).mean(1);
}

}  // namespace

torch::Tensor GeneratorGanLoss(const torch::Tensor& fake_logits) {
  return torch::nn::functional::softplus(-PerSample(fake_logits));
}

torch::Tensor DiscriminatorGanLoss(const torch::Tensor& real_logits, const torch::Tensor& fake_logits) {
  AVATAR_CHECK_INPUT(real_logits.size(0) == fake_logits.size(0)) << "GAN loss: real and fake batches differ";
  return torch::nn::functional::softplus(PerSample(fake_logits)) +
         torch::nn::functional::softplus(-PerSample(real_logits));
}

torch::Tensor R1Penalty(const torch::Tensor& real_logits, const std::vector<torch::Tensor>& inputs) {
  AVATAR_CHECK_INPUT(!inputs.empty()) << "R1: no inputs";
  for (const auto& x : inputs)
    AVATAR_CHECK_INPUT(x.defined() && x.requires_grad() && x.size(0) == real_logits.size(0))
        << "R1: every input must require grad and share the logits' batch";
  const std::vector<torch::Tensor> grads =
      torch::autograd::grad({real_logits.sum()}, inputs, /*grad_outputs=*/{}, /*retain_graph=*/true,
                            /*create_graph=*/true);
  torch::Tensor penalty;
  for (const auto& g : grads) {
    const torch::Tensor s = g.pow(2).reshape({g.size(0), -1}).sum(1);
    penalty = penalty.defined() ? penalty + s : s;
  }
  return penalty;
}

}  // namespace avatar::train
