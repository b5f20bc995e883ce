// The trainer's options, curriculum, construction and evaluation; steps, state and run loop have own files.

#include "core/train/trainer.h"

#include <cmath>
#include <exception>
#include <string>

#include "core/render/camera.h"
#include "core/train/losses.h"
#include "core/util/error.h"

namespace avatar::train {

void TrainerOptions::Validate() const {
  AVATAR_CHECK_OPTION(lr > 0 && std::isfinite(lr)) << "lr must be > 0";
  AVATAR_CHECK_OPTION(beta1 >= 0 && beta1 < 1 && beta2 >= 0 && beta2 < 1) << "Adam betas must be in [0,1)";
  AVATAR_CHECK_OPTION(eps > 0) << "eps must be > 0";
  AVATAR_CHECK_OPTION(perceptual_weight >= 0 && neutral_weight >= 0 && tv_weight >= 0) << "loss weights must be >= 0";
  AVATAR_CHECK_OPTION(tv_points >= 1 && tv_sigma >= 0) << "tv_points must be >= 1 and tv_sigma >= 0";
  AVATAR_CHECK_OPTION(expression_start >= 0 && appearance_start >= expression_start)
      << "curriculum: 0 <= expression_start <= appearance_start";
  AVATAR_CHECK_OPTION(max_bad_steps >= 1) << "max_bad_steps must be >= 1";
  AVATAR_CHECK_OPTION(seed >= 0) << "seed must be >= 0";
  AVATAR_CHECK_OPTION(stage == 1 || stage == 2) << "stage must be 1 or 2";
  AVATAR_CHECK_OPTION(gan_weight >= 0 && std::isfinite(gan_weight)) << "gan_weight must be >= 0";
  AVATAR_CHECK_OPTION(r1_gamma >= 0 && std::isfinite(r1_gamma)) << "r1_gamma must be >= 0";
  AVATAR_CHECK_OPTION(r1_every >= 1) << "r1_every must be >= 1";
  AVATAR_CHECK_OPTION(d_lr > 0 && std::isfinite(d_lr)) << "d_lr must be > 0";
  AVATAR_CHECK_OPTION(patch_size >= 0) << "patch_size must be >= 0 (0 = whole images), got " << patch_size;
  AVATAR_CHECK_OPTION(grad_chunk_rays >= 0) << "grad_chunk_rays must be >= 0 (0 = off), got " << grad_chunk_rays;
  try {
    (void)torch::Device(device);
  } catch (const std::exception&) {
    throw InvalidOptions("unknown device '" + device + "' (cpu, cuda, cuda:N)");
  }
}

void TrainerOptions::ScheduleFor(int64_t total_steps) {
  // The paper: 750k stage-I steps, expression planes from 120k, appearance planes from 240k.
  expression_start = total_steps * 120 / 750;
  appearance_start = total_steps * 240 / 750;
}

StageOneTrainer::StageOneTrainer(GohaModel model, const TrainerOptions& options, PerceptualFn perceptual)
    : options_(options), device_(torch::kCPU), model_(std::move(model)), perceptual_(std::move(perceptual)) {
  options_.Validate();
  AVATAR_CHECK_INPUT(!model_.is_empty()) << "StageOneTrainer: no model";
  device_ = torch::Device(options_.device);
  model_->to(device_);
  // Stage II optimises the super-resolution module only; modules an ablation switches off
  // (FrozenByConfig) are never optimised.
  for (const auto& item : model_->named_parameters(true)) {
    if (options_.stage == 2 && item.key().rfind("super_resolution.", 0) != 0) continue;
    if (FrozenByConfig(model_->config(), item.key())) continue;
    names_.push_back(item.key());
    params_.push_back(item.value());
  }
  AVATAR_CHECK(!params_.empty()) << "StageOneTrainer: no parameters to train";
  exp_avg_.resize(params_.size());
  exp_avg_sq_.resize(params_.size());
  param_steps_.assign(params_.size(), 0);
  torch::manual_seed(static_cast<uint64_t>(options_.seed));
  if (options_.stage == 2) {
    disc_ = DualDiscriminator(model_->config());
    disc_->to(device_);
    disc_->train();
    for (const auto& item : disc_->named_parameters(true)) {
      d_names_.push_back(item.key());
      d_params_.push_back(item.value());
    }
    d_exp_avg_.resize(d_params_.size());
    d_exp_avg_sq_.resize(d_params_.size());
    d_param_steps_.assign(d_params_.size(), 0);
  }
}

bool FrozenByConfig(const ModelConfig& config, const std::string& name) {
  const auto starts = [&name](const char* prefix) { return name.rfind(prefix, 0) == 0; };
  if (!config.appearance_branch && (starts("appearance_encoder.") || starts("appearance_upsampler"))) return true;
  if (config.expression_bases() && (starts("expression_encoder.") || starts("expression_head."))) return true;
  return false;
}

std::string StageOneTrainer::PhaseAt(int64_t step) const {
  if (options_.stage == 2) return "super_resolution";
  if (step < options_.expression_start) return "canonical";
  if (step < options_.appearance_start || !model_->config().appearance_branch) return "expression";
  return "appearance";
}

StageOneTrainer::Renders StageOneTrainer::Evaluate(const TrainBatch& batch) {
  torch::NoGradGuard no_grad;
  model_->eval();
  const TrainBatch b = batch.To(device_);
  const int64_t res = model_->config().render_size;
  Renders out;
  out.target = ResizeTo(Matte(b.target, b.target_matte), res);
  const render::Cameras source_cam = render::CamerasFromLabels(b.source_label);
  const render::Cameras target_cam = render::CamerasFromLabels(b.target_label);
  const torch::Tensor tc = model_->CanonicalPlanes(b.source);
  const torch::Tensor tce = tc + model_->ExpressionPlanesFor(b.expression_image, b.target_expression);
  out.canonical = model_->Render(tc, target_cam, 0, true).rgb;
  out.expression = model_->Render(tce, target_cam, 0, true).rgb;
  if (model_->config().appearance_branch) {
    const torch::Tensor tp =
        model_->AppearancePlanes(b.source, b.source_eye_mouth, b.source_matte, tc, source_cam).planes;
    out.full = model_->Render(tce + tp, target_cam, 0, true).rgb;
  } else {
    out.full = out.expression;  // no appearance branch: the output is I_c+e
  }
  out.source = b.source;
  if (options_.stage == 2) out.super_resolved = model_->SuperResolve(out.full);
  model_->train();
  return out;
}

}  // namespace avatar::train
