// Stage I's step: the curriculum's loss terms and renders; its FinishStep (Adam) ends stage II's steps too.

#include "core/train/trainer.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <string>
#include <vector>

#include "core/render/camera.h"
#include "core/render/renderer.h"
#include "core/train/losses.h"
#include "core/train/trainer_internal.h"
#include "core/util/error.h"
#include "core/util/timer.h"

namespace avatar::train {

namespace {

// One Adam update (see the header comment) of the parameters with gradients, clipped to `clip`.
void AdamUpdate(const std::vector<torch::Tensor>& params, std::vector<torch::Tensor>& exp_avg,
                std::vector<torch::Tensor>& exp_avg_sq, std::vector<int64_t>& steps, double grad_norm, double clip,
                double lr, double b1, double b2, double eps) {
  torch::NoGradGuard no_grad;
  const double scale = (clip > 0 && grad_norm > clip) ? clip / (grad_norm + 1e-6) : 1.0;
  for (size_t i = 0; i < params.size(); ++i) {
    torch::Tensor g = params[i].grad();
    if (!g.defined()) continue;
    if (scale != 1.0) g = g * scale;
    if (!exp_avg[i].defined()) {
      exp_avg[i] = torch::zeros_like(params[i]);
      exp_avg_sq[i] = torch::zeros_like(params[i]);
    }
    const int64_t t = ++steps[i];
    exp_avg[i].mul_(b1).add_(g, 1.0 - b1);
    exp_avg_sq[i].mul_(b2).addcmul_(g, g, 1.0 - b2);
    const double bc1 = 1.0 - std::pow(b1, static_cast<double>(t));
    const double bc2 = 1.0 - std::pow(b2, static_cast<double>(t));
    const torch::Tensor denom = (exp_avg_sq[i].sqrt() / std::sqrt(bc2)).add_(eps);
    params[i].addcdiv_(exp_avg[i], denom, -lr / bc1);
  }
}

// The windows [B,C,size,size] of images [B,C,H,W] whose top-left pixels (row, column) are
// corners [B,2] (CPU int64).
torch::Tensor CropWindows(const torch::Tensor& images, const torch::Tensor& corners, int64_t size) {
  const auto at = corners.accessor<int64_t, 2>();
  std::vector<torch::Tensor> crops;
  for (int64_t i = 0; i < images.size(0); ++i)
    crops.push_back(images[i].narrow(1, at[i][0], size).narrow(2, at[i][1], size));
  return torch::stack(crops);
}

}  // namespace

std::map<std::string, torch::Tensor> StageOneTrainer::LossTerms(const TrainBatch& b, int64_t step) {
  const int64_t res = model_->config().render_size;
  const bool with_expression = step >= options_.expression_start;
  // The w/o-appearance ablation (config.appearance_branch false) never adds T_p.
  const bool with_appearance = step >= options_.appearance_start && model_->config().appearance_branch;
  // Which terms this step has (the release's rotation, when on, after the canonical phase).
  bool recon = true, full = with_appearance, neutral = true;
  if (options_.rotation && with_expression) {
    const int64_t k = step % 6;
    recon = k < 4;
    full = with_appearance && k < 2;
    neutral = k >= 4;
  }

  const render::Cameras source_cam = render::CamerasFromLabels(b.source_label);
  const render::Cameras target_cam = render::CamerasFromLabels(b.target_label);
  torch::Tensor target = ResizeTo(Matte(b.target, b.target_matte), res);
  // Patches: one window per sample for the target-camera renders, from the global CPU generator
  // (its state is part of the training state), and the same window of the target.
  torch::Tensor corners;
  if (recon && options_.patch_size > 0 && options_.patch_size < res) {
    corners = torch::randint(res - options_.patch_size + 1, {b.size(), 2}, torch::TensorOptions().dtype(torch::kLong));
    target = CropWindows(target, corners, options_.patch_size);
  }

  std::map<std::string, torch::Tensor> terms;
  const torch::Tensor tc = model_->CanonicalPlanes(b.source);
  torch::Tensor largest = tc;
  CheckCancel();
  if (recon) {
    terms["canonical"] =
        ImageLoss(TrainingRender(tc, target_cam, corners), target, perceptual_, options_.perceptual_weight).mean();
    if (with_expression) {
      CheckCancel();
      const torch::Tensor tce = tc + model_->ExpressionPlanesFor(b.expression_image, b.target_expression);
      largest = tce;
      terms["expression"] =
          ImageLoss(TrainingRender(tce, target_cam, corners), target, perceptual_, options_.perceptual_weight).mean();
      if (full) {
        CheckCancel();
        const torch::Tensor tp =
            model_->AppearancePlanes(b.source, b.source_eye_mouth, b.source_matte, tc, source_cam).planes;
        const torch::Tensor tcep = tce + tp;
        largest = tcep;
        terms["appearance"] =
            ImageLoss(TrainingRender(tcep, target_cam, corners), target, perceptual_, options_.perceptual_weight)
                .mean();
      }
    }
  }
  if (neutral && options_.neutral_weight > 0) {
    CheckCancel();
    const torch::Tensor ic_source = TrainingRender(tc, source_cam);
    terms["neutral"] =
        options_.neutral_weight *
        NeutralLoss(ic_source, b.neutral_image, b.neutral_mask, perceptual_, options_.perceptual_weight).mean();
  }
  if (options_.tv_weight > 0) {
    TvOptions tv;
    tv.num_points = options_.tv_points;
    tv.sigma = options_.tv_sigma;
    tv.box_warp = model_->RenderOptionsFor().box_warp;
    auto decoder = [this](const torch::Tensor& f) { return model_->decoder->forward(f); };
    const render::Field field = render::MakeTriplaneField(largest, decoder, tv.box_warp);
    const DensityFn density = [&field](const torch::Tensor& points) { return field(points).raw_density; };
    terms["tv"] = options_.tv_weight * DensityTvLoss(density, b.size(), tv, largest.options());
  }

  return terms;
}

torch::Tensor StageOneTrainer::TrainingRender(const torch::Tensor& planes, const render::Cameras& cameras,
                                              const torch::Tensor& corners) {
  render::RenderOptions opts = model_->RenderOptionsFor(0, options_.deterministic_render);
  if (corners.defined()) {
    opts.window_size = static_cast<int>(options_.patch_size);
    opts.window_corners = corners;
  }
  if (options_.grad_chunk_rays > 0) {
    opts.grad_chunk_rays = static_cast<int>(std::min<int64_t>(options_.grad_chunk_rays, 1 << 30));
    for (const auto& p : model_->decoder->parameters()) opts.grad_parameters.push_back(p);
  }
  return model_->RenderWith(planes, cameras, opts).rgb;
}

void StageOneTrainer::FinishStep(bool ok, StepResult& r, const Timer& timer) {
  if (ok) {
    AdamUpdate(params_, exp_avg_, exp_avg_sq_, param_steps_, r.grad_norm, options_.grad_clip, options_.lr,
               options_.beta1, options_.beta2, options_.eps);
    if (!d_params_.empty())
      AdamUpdate(d_params_, d_exp_avg_, d_exp_avg_sq_, d_param_steps_, r.d_grad_norm, options_.grad_clip,
                 options_.d_lr, options_.beta1, options_.beta2, options_.eps);
    bad_in_a_row_ = 0;
  } else {
    r.skipped = true;
    ++skipped_;
    ++bad_in_a_row_;
  }
  detail::ClearGrads(params_);
  detail::ClearGrads(d_params_);
  ++step_;
  r.seconds = timer.Seconds();
}

StepResult StageOneTrainer::Step(const TrainBatch& batch) {
  if (options_.stage == 2) return StepStageTwo(batch);
  Timer timer;
  StepResult r;
  r.step = step_;
  r.phase = PhaseAt(step_);
  AVATAR_CHECK_INPUT(batch.size() >= 1) << "training step on an empty batch";
  model_->train();
  const TrainBatch b = batch.To(device_);
  detail::ClearGrads(params_);
  const std::map<std::string, torch::Tensor> terms = LossTerms(b, step_);

  const torch::Tensor total = detail::SumTerms(terms, r.terms);
  r.loss = total.item<double>();
  bool ok = std::isfinite(r.loss);
  if (!ok) r.skip_reason = "non-finite loss";
  CheckCancel();
  if (ok) total.backward();
  CheckCancel();  // Before the update: a cancelled step changes nothing (the next Step clears the gradients).
  if (reducer_) {
    // Data parallelism: the gradients and reported losses averaged over the ranks, so that the
    // checks and the update below are the same on every rank.
    ok = detail::ReduceOverRanks(*reducer_, ok, {&r.loss}, {{&r.terms, detail::KeysOf(r.terms)}}, params_, r);
  }
  if (ok) ok = detail::FiniteGradNorm(params_, device_, r.grad_norm, r.skip_reason, "non-finite gradient");
  FinishStep(ok, r, timer);
  return r;
}

}  // namespace avatar::train
