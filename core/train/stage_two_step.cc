// Stage II's step: the super-resolution module against the dual discriminator, stage I frozen.

#include "core/train/trainer.h"

#include <cmath>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "core/render/camera.h"
#include "core/train/gan.h"
#include "core/train/losses.h"
#include "core/train/trainer_internal.h"
#include "core/util/error.h"
#include "core/util/timer.h"

namespace avatar::train {

namespace {

void SetRequiresGrad(std::vector<torch::Tensor>& params, bool on) {
  for (auto& p : params) p.requires_grad_(on);
}

// Replaces the SR's noise maps with fresh N(0,1) draws and puts the fixed ones back when it
// goes out of scope (after the backward pass that used them).
class RandomNoiseScope {
 public:
  RandomNoiseScope(GohaModel& model, bool on) {
    if (!on) return;
    torch::NoGradGuard no_grad;
    for (auto& item : model->super_resolution->named_buffers(true)) {
      const std::string& key = item.key();
      if (key.size() < 5 || key.compare(key.size() - 5, 5, "noise") != 0) continue;
      torch::Tensor buffer = item.value();
      saved_.emplace_back(buffer, buffer.clone());
      buffer.copy_(torch::randn_like(buffer));
    }
  }
  ~RandomNoiseScope() {
    torch::NoGradGuard no_grad;
    for (auto& [buffer, fixed] : saved_) buffer.copy_(fixed);
  }
  RandomNoiseScope(const RandomNoiseScope&) = delete;
  RandomNoiseScope& operator=(const RandomNoiseScope&) = delete;

 private:
  std::vector<std::pair<torch::Tensor, torch::Tensor>> saved_;
};

}  // namespace

StepResult StageOneTrainer::StepStageTwo(const TrainBatch& batch) {
  Timer timer;
  StepResult r;
  r.step = step_;
  r.phase = PhaseAt(step_);
  AVATAR_CHECK_INPUT(batch.size() >= 1) << "training step on an empty batch";
  model_->train();
  disc_->train();
  const TrainBatch b = batch.To(device_);
  const ModelConfig& config = model_->config();
  detail::ClearGrads(params_);
  detail::ClearGrads(d_params_);

  const render::Cameras source_cam = render::CamerasFromLabels(b.source_label);
  const render::Cameras target_cam = render::CamerasFromLabels(b.target_label);
  const torch::Tensor matted = Matte(b.target, b.target_matte);
  const torch::Tensor real_low = ResizeTo(matted, config.render_size);
  const torch::Tensor real_high = ResizeTo(matted, config.sr_size);
  torch::Tensor low;
  {
    // The frozen stage-I network: one render of the full plane sum at the target camera.
    torch::NoGradGuard no_grad;
    const torch::Tensor tc = model_->CanonicalPlanes(b.source);
    torch::Tensor planes = tc + model_->ExpressionPlanesFor(b.expression_image, b.target_expression);
    if (config.appearance_branch)
      planes = planes + model_->AppearancePlanes(b.source, b.source_eye_mouth, b.source_matte, tc, source_cam).planes;
    low = model_->Render(planes, target_cam, 0, options_.deterministic_render).rgb;
  }

  // Generator (SR) terms; D's parameters take no gradient from them.
  std::map<std::string, torch::Tensor> terms;
  torch::Tensor fake;
  bool ok = true;
  {
    RandomNoiseScope noise(model_, options_.sr_random_noise);
    fake = model_->SuperResolve(low);
    terms["sr"] = ImageLoss(fake, real_high, perceptual_, options_.perceptual_weight).mean();
    if (options_.gan_weight > 0) {
      SetRequiresGrad(d_params_, false);
      terms["gan"] = options_.gan_weight * GeneratorGanLoss(disc_->forward(fake, low)).mean();
      SetRequiresGrad(d_params_, true);
    }
    const torch::Tensor total = detail::SumTerms(terms, r.terms);
    r.loss = total.item<double>();
    ok = std::isfinite(r.loss);
    if (!ok) r.skip_reason = "non-finite loss";
    if (ok) {
      total.backward();
      // With a reducer the gradients are checked after they are averaged over the ranks.
      if (!reducer_) ok = detail::FiniteGradNorm(params_, device_, r.grad_norm, r.skip_reason, "non-finite gradient");
    }
  }

  // Discriminator: fake = (I_hr, I), real = (target at S, target at r); lazy R1 on the real pair.
  if (ok) {
    const bool r1 = options_.r1_gamma > 0 && step_ % options_.r1_every == 0;
    torch::Tensor rh = real_high.detach(), rl = real_low.detach();
    if (r1) {
      rh = rh.clone().requires_grad_(true);
      rl = rl.clone().requires_grad_(true);
    }
    const torch::Tensor fake_logits = disc_->forward(fake.detach(), low);
    const torch::Tensor real_logits = disc_->forward(rh, rl);
    const torch::Tensor d_gan = DiscriminatorGanLoss(real_logits, fake_logits).mean();
    torch::Tensor d_total = d_gan;
    r.d_terms["d"] = d_gan.item<double>();
    r.d_terms["real_logit"] = real_logits.mean().item<double>();
    r.d_terms["fake_logit"] = fake_logits.mean().item<double>();
    if (r1) {
      const torch::Tensor penalty =
          0.5 * options_.r1_gamma * static_cast<double>(options_.r1_every) * R1Penalty(real_logits, {rh, rl}).mean();
      d_total = d_total + penalty;
      r.d_terms["r1"] = penalty.item<double>();
    }
    r.d_loss = d_total.item<double>();
    ok = std::isfinite(r.d_loss);
    if (!ok) r.skip_reason = "non-finite discriminator loss";
    if (ok) {
      d_total.backward();
      if (!reducer_) {
        ok = detail::FiniteGradNorm(d_params_, device_, r.d_grad_norm, r.skip_reason,
                                    "non-finite discriminator gradient");
      }
    }
  }
  if (reducer_) {
    // Data parallelism: G's and D's gradients and the reported numbers averaged over the ranks
    // (D's terms are fixed by the step: a rank that stopped before D reports NaN for them).
    std::vector<std::string> d_keys = {"d", "real_logit", "fake_logit"};
    if (options_.r1_gamma > 0 && step_ % options_.r1_every == 0) d_keys.push_back("r1");
    std::vector<torch::Tensor> all = params_;
    all.insert(all.end(), d_params_.begin(), d_params_.end());
    if (!ok) r.d_loss = std::nan("");
    ok = detail::ReduceOverRanks(*reducer_, ok, {&r.loss, &r.d_loss},
                                 {{&r.terms, detail::KeysOf(r.terms)}, {&r.d_terms, d_keys}}, all, r);
    if (ok) {
      r.grad_norm = detail::GradNorm(params_, device_);
      r.d_grad_norm = detail::GradNorm(d_params_, device_);
      ok = std::isfinite(r.grad_norm) && std::isfinite(r.d_grad_norm);
      if (!ok) r.skip_reason = std::isfinite(r.grad_norm) ? "non-finite discriminator gradient" : "non-finite gradient";
    }
  }
  FinishStep(ok, r, timer);
  return r;
}

}  // namespace avatar::train
