#include "core/train/trainer.h"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <sstream>

#include "core/io/atomic_file.h"
#include "core/model/checkpoint.h"
#include "core/render/camera.h"
#include "core/train/gan.h"
#include "core/util/error.h"
#include "core/util/options.h"
#include "core/util/progress_line.h"
#include "core/util/timer.h"

namespace avatar::train {

namespace fs = std::filesystem;

namespace {

constexpr const char* kStateKind = "goha-train-state";

bool Finite(const torch::Tensor& t) {
  if (!t.defined() || !t.is_floating_point()) return true;
  return torch::isfinite(t).all().item<bool>();
}

std::string FormatDuration(double seconds) {
  if (!std::isfinite(seconds) || seconds < 0) return "?";
  const int64_t s = static_cast<int64_t>(seconds + 0.5);
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%lld:%02lld:%02lld", static_cast<long long>(s / 3600),
                static_cast<long long>((s / 60) % 60), static_cast<long long>(s % 60));
  return buf;
}

at::Generator DefaultGenerator(const torch::Device& device) {
  return at::globalContext().defaultGenerator(device.is_cpu() ? torch::Device(torch::kCPU) : device);
}

// Global L2 norm of the gradients (float64), or NaN when one is not finite.
double GradNorm(const std::vector<torch::Tensor>& params, const torch::Device& device) {
  torch::Tensor sq = torch::zeros({}, torch::TensorOptions().dtype(torch::kFloat64).device(device));
  for (const auto& p : params)
    if (p.grad().defined()) sq += p.grad().to(torch::kFloat64).pow(2).sum();
  return std::sqrt(sq.item<double>());
}

// The sum of the weighted loss terms; each term's batch mean is logged into `logged`.
torch::Tensor SumTerms(const std::map<std::string, torch::Tensor>& terms, std::map<std::string, double>& logged) {
  torch::Tensor total;
  for (const auto& [name, t] : terms) {
    total = total.defined() ? total + t : t;
    logged[name] = t.item<double>();
  }
  return total;
}

// Measures the gradient norm into `norm`; false (with `reason`) when it is not finite.
bool FiniteGradNorm(const std::vector<torch::Tensor>& params, const torch::Device& device, double& norm,
                    std::string& reason, const char* what) {
  norm = GradNorm(params, device);
  if (std::isfinite(norm)) return true;
  reason = what;
  return false;
}

// Adam moments of `names` into the archive as <m>NAME / <v>NAME (parameters never stepped have none).
void StoreAdamMoments(TensorArchive& archive, const std::vector<std::string>& names,
                      const std::vector<torch::Tensor>& exp_avg, const std::vector<torch::Tensor>& exp_avg_sq,
                      const std::string& m, const std::string& v) {
  for (size_t i = 0; i < names.size(); ++i) {
    if (!exp_avg[i].defined()) continue;
    archive.tensors.emplace_back(m + names[i], exp_avg[i]);
    archive.tensors.emplace_back(v + names[i], exp_avg_sq[i]);
  }
}

// The inverse of StoreAdamMoments, with the per-parameter step counts `step_counts` (JSON array).
void RestoreAdamMoments(const TensorArchive& archive, const std::string& file, const std::vector<std::string>& names,
                        const nlohmann::json& step_counts, std::vector<int64_t>& steps,
                        std::vector<torch::Tensor>& exp_avg, std::vector<torch::Tensor>& exp_avg_sq,
                        const std::string& m, const std::string& v, const torch::Device& device,
                        const char* what) {
  if (step_counts.size() != names.size()) throw ModelLoad(file + ": " + what + " state of another model");
  for (size_t i = 0; i < names.size(); ++i) {
    steps[i] = step_counts[i].get<int64_t>();
    exp_avg[i] = torch::Tensor();
    exp_avg_sq[i] = torch::Tensor();
    if (steps[i] == 0) continue;
    exp_avg[i] = archive.Get(m + names[i], file).to(device).clone();
    exp_avg_sq[i] = archive.Get(v + names[i], file).to(device).clone();
  }
}

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

void ClearGrads(std::vector<torch::Tensor>& params) {
  for (auto& p : params) p.mutable_grad() = torch::Tensor();
}

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

std::vector<std::string> KeysOf(const std::map<std::string, double>& m) {
  std::vector<std::string> keys;
  for (const auto& item : m) keys.push_back(item.first);
  return keys;
}

// Data parallelism: the gradients of `params` and the step's reported numbers (`scalars`, and
// the entries `keys` of each map; an entry a rank lacks counts as NaN) averaged over the ranks.
// Returns whether every rank's loss was finite; when only another rank's was not, says so in
// r.skip_reason.
using MapKeys = std::pair<std::map<std::string, double>*, std::vector<std::string>>;
bool ReduceOverRanks(GradientReducer& reducer, bool local_ok, const std::vector<double*>& scalars,
                     const std::vector<MapKeys>& maps, const std::vector<torch::Tensor>& params, StepResult& r) {
  std::vector<double> values;
  for (const double* v : scalars) values.push_back(*v);
  for (const auto& [map, keys] : maps)
    for (const auto& key : keys) {
      const auto it = map->find(key);
      values.push_back(it != map->end() ? it->second : std::nan(""));
    }
  const bool all_ok = reducer.ReduceGradients(params, local_ok, values);
  size_t i = 0;
  for (double* v : scalars) *v = values[i++];
  for (const auto& [map, keys] : maps)
    for (const auto& key : keys) (*map)[key] = values[i++];
  if (local_ok && !all_ok) r.skip_reason = "non-finite loss on another rank";
  return all_ok;
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

ModelConfig ReadStateModelConfig(const fs::path& path) {
  const TensorArchive archive = ReadTensorArchive(path, kStateKind);
  try {
    return ModelConfigFromJson(archive.meta.at("config").dump());
  } catch (const nlohmann::json::exception& e) {
    throw ModelLoad(path.string() + ": malformed training state (" + e.what() + ")");
  } catch (const InvalidOptions& e) {
    throw ModelLoad(path.string() + ": the training state holds an invalid model config: " + e.what());
  }
}

void StageOneTrainer::InitFromCheckpoint(const fs::path& path) {
  const LoadedModel loaded = LoadModelCheckpoint(path);
  const ModelConfig& stored = loaded.model->config();
  // The ablation fields may differ (e.g. expression bases trained from encoder weights): every
  // tensor the two networks share is taken, the bases start afresh.
  const auto sizes_only = [](const ModelConfig& c) {
    nlohmann::json j = nlohmann::json::parse(ModelConfigToJson(c));
    for (const char* k : {"appearance_branch", "expression_model", "expression_coefficients"}) j.erase(k);
    return j;
  };
  const nlohmann::json a = sizes_only(stored), b = sizes_only(model_->config());
  if (a != b) {
    std::string differ;
    for (auto it = a.begin(); it != a.end(); ++it)
      if (!b.contains(it.key()) || b.at(it.key()) != it.value()) differ += (differ.empty() ? "" : ", ") + it.key();
    throw InvalidOptions(path.string() + ": the checkpoint is of model config '" + stored.name +
                         "', not of the model being trained ('" + model_->config().name + "'; fields that differ: " +
                         differ + "); train with the checkpoint's config");
  }
  torch::NoGradGuard no_grad;
  GohaModel source = loaded.model;
  const auto src_params = source->named_parameters(true);
  const auto src_buffers = source->named_buffers(true);
  // Tensors only this network has: the expression bases of a bases model initialised from an
  // encoder model (they keep their initialisation; the std buffer keeps what was set).
  const auto fresh = [&](const std::string& name) {
    return model_->config().expression_bases() && !stored.expression_bases() &&
           (name == "expression_bases" || name == "expression_std");
  };
  const auto take = [&](const std::string& name, torch::Tensor& dst, const torch::Tensor* src) {
    if (src == nullptr && fresh(name)) return;
    if (src == nullptr || src->sizes() != dst.sizes())
      throw ModelLoad(path.string() + ": tensor '" + name + "' does not match the model");
    dst.copy_(*src);
  };
  for (auto& item : model_->named_parameters(true)) take(item.key(), item.value(), src_params.find(item.key()));
  for (auto& item : model_->named_buffers(true)) take(item.key(), item.value(), src_buffers.find(item.key()));
  step_ = loaded.info.step;
  sr_trained_before_ = loaded.info.sr_trained;
}

std::string StageOneTrainer::PhaseAt(int64_t step) const {
  if (options_.stage == 2) return "super_resolution";
  if (step < options_.expression_start) return "canonical";
  if (step < options_.appearance_start || !model_->config().appearance_branch) return "expression";
  return "appearance";
}

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
  ClearGrads(params_);
  ClearGrads(d_params_);
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
  ClearGrads(params_);
  const std::map<std::string, torch::Tensor> terms = LossTerms(b, step_);

  const torch::Tensor total = SumTerms(terms, r.terms);
  r.loss = total.item<double>();
  bool ok = std::isfinite(r.loss);
  if (!ok) r.skip_reason = "non-finite loss";
  CheckCancel();
  if (ok) total.backward();
  CheckCancel();  // Before the update: a cancelled step changes nothing (the next Step clears the gradients).
  if (reducer_) {
    // Data parallelism: the gradients and reported losses averaged over the ranks, so that the
    // checks and the update below are the same on every rank.
    ok = ReduceOverRanks(*reducer_, ok, {&r.loss}, {{&r.terms, KeysOf(r.terms)}}, params_, r);
  }
  if (ok) ok = FiniteGradNorm(params_, device_, r.grad_norm, r.skip_reason, "non-finite gradient");
  FinishStep(ok, r, timer);
  return r;
}

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
  ClearGrads(params_);
  ClearGrads(d_params_);

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
    const torch::Tensor total = SumTerms(terms, r.terms);
    r.loss = total.item<double>();
    ok = std::isfinite(r.loss);
    if (!ok) r.skip_reason = "non-finite loss";
    if (ok) {
      total.backward();
      // With a reducer the gradients are checked after they are averaged over the ranks.
      if (!reducer_) ok = FiniteGradNorm(params_, device_, r.grad_norm, r.skip_reason, "non-finite gradient");
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
        ok = FiniteGradNorm(d_params_, device_, r.d_grad_norm, r.skip_reason, "non-finite discriminator gradient");
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
    ok = ReduceOverRanks(*reducer_, ok, {&r.loss, &r.d_loss}, {{&r.terms, KeysOf(r.terms)}, {&r.d_terms, d_keys}}, all,
                         r);
    if (ok) {
      r.grad_norm = GradNorm(params_, device_);
      r.d_grad_norm = GradNorm(d_params_, device_);
      ok = std::isfinite(r.grad_norm) && std::isfinite(r.d_grad_norm);
      if (!ok) r.skip_reason = std::isfinite(r.grad_norm) ? "non-finite discriminator gradient" : "non-finite gradient";
    }
  }
  FinishStep(ok, r, timer);
  return r;
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

void StageOneTrainer::SyncFromRankZero() {
  if (!reducer_) return;
  std::vector<double> at = {static_cast<double>(step_), -static_cast<double>(step_)};
  reducer_->AllMax(at);
  if (at[0] != -at[1])
    throw InvalidInput("data-parallel training: the ranks start at different steps (" + std::to_string(-at[1]) +
                       " to " + std::to_string(at[0]) +
                       "); every rank must resume the same RUN/state.ckpt "
                       "(a run folder shared by all ranks) or start afresh");
  torch::NoGradGuard no_grad;
  std::vector<torch::Tensor> tensors;
  for (const auto& p : model_->parameters(true)) tensors.push_back(p.detach());
  for (const auto& b : model_->buffers(true)) tensors.push_back(b);
  if (!disc_.is_empty()) {
    for (const auto& p : disc_->parameters(true)) tensors.push_back(p.detach());
    for (const auto& b : disc_->buffers(true)) tensors.push_back(b);
  }
  // Adam moments where rank 0 has them (a rank that lacks one starts it at zero to receive it).
  auto moments = [&](std::vector<torch::Tensor>& params, std::vector<torch::Tensor>& m, std::vector<torch::Tensor>& v,
                     std::vector<int64_t>& steps) {
    std::vector<torch::Tensor> counts = {torch::empty({static_cast<int64_t>(steps.size())}, torch::kFloat64)};
    for (size_t i = 0; i < steps.size(); ++i) counts[0][static_cast<int64_t>(i)] = static_cast<double>(steps[i]);
    reducer_->Broadcast(counts);
    for (size_t i = 0; i < steps.size(); ++i) {
      steps[i] = static_cast<int64_t>(counts[0][static_cast<int64_t>(i)].item<double>());
      if (steps[i] == 0) continue;
      if (!m[i].defined()) m[i] = torch::zeros_like(params[i]);
      if (!v[i].defined()) v[i] = torch::zeros_like(params[i]);
      tensors.push_back(m[i]);
      tensors.push_back(v[i]);
    }
  };
  moments(params_, exp_avg_, exp_avg_sq_, param_steps_);
  if (!disc_.is_empty()) moments(d_params_, d_exp_avg_, d_exp_avg_sq_, d_param_steps_);
  reducer_->Broadcast(tensors);
}

bool StageOneTrainer::AllFinite() const {
  for (const auto& p : params_)
    if (!Finite(p)) return false;
  for (const auto& item : model_->named_buffers(true))
    if (!Finite(item.value())) return false;
  for (size_t i = 0; i < params_.size(); ++i)
    if (!Finite(exp_avg_[i]) || !Finite(exp_avg_sq_[i])) return false;
  for (size_t i = 0; i < d_params_.size(); ++i)
    if (!Finite(d_params_[i]) || !Finite(d_exp_avg_[i]) || !Finite(d_exp_avg_sq_[i])) return false;
  return true;
}

void StageOneTrainer::SaveState(const fs::path& path, const BatchSource* source) const {
  SaveStateAt(path, source != nullptr ? source->State() : nlohmann::json());
}

void StageOneTrainer::SaveStateAt(const fs::path& path, const nlohmann::json& data_cursor) const {
  if (!AllFinite())
    throw InvalidInput(path.string() + ": not written: the training state has a non-finite tensor");
  TensorArchive archive;
  archive.kind = kStateKind;
  nlohmann::json steps = nlohmann::json::array();
  for (int64_t s : param_steps_) steps.push_back(s);
  archive.meta = {{"config", nlohmann::json::parse(ModelConfigToJson(model_->config()))},
                  {"options", options::ToJson(options_)},
                  {"step", step_},
                  {"skipped", skipped_},
                  {"bad_in_a_row", bad_in_a_row_},
                  {"param_steps", steps},
                  {"stage", options_.stage},
                  {"sr_trained_before", sr_trained_before_},
                  {"data", data_cursor}};
  for (const auto& item : model_->named_parameters(true)) archive.tensors.emplace_back("w/" + item.key(), item.value());
  for (const auto& item : model_->named_buffers(true)) archive.tensors.emplace_back("w/" + item.key(), item.value());
  StoreAdamMoments(archive, names_, exp_avg_, exp_avg_sq_, "m/", "v/");
  if (!disc_.is_empty()) {
    nlohmann::json d_steps = nlohmann::json::array();
    for (int64_t s : d_param_steps_) d_steps.push_back(s);
    archive.meta["d_param_steps"] = d_steps;
    for (const auto& item : disc_->named_parameters(true)) archive.tensors.emplace_back("d/" + item.key(), item.value());
    for (const auto& item : disc_->named_buffers(true)) archive.tensors.emplace_back("d/" + item.key(), item.value());
    StoreAdamMoments(archive, d_names_, d_exp_avg_, d_exp_avg_sq_, "dm/", "dv/");
  }
  {
    at::Generator cpu = DefaultGenerator(torch::kCPU);
    std::lock_guard<std::mutex> lock(cpu.mutex());
    archive.tensors.emplace_back("rng/cpu", cpu.get_state());
  }
  if (!device_.is_cpu()) {
    at::Generator dev = DefaultGenerator(device_);
    std::lock_guard<std::mutex> lock(dev.mutex());
    archive.tensors.emplace_back("rng/device", dev.get_state());
  }
  WriteTensorArchive(path, archive);
}

void StageOneTrainer::LoadState(const fs::path& path, BatchSource* source) {
  const TensorArchive archive = ReadTensorArchive(path, kStateKind);
  const std::string file = path.string();
  try {
    const ModelConfig stored = ModelConfigFromJson(archive.meta.at("config").dump());
    if (stored != model_->config()) {
      const nlohmann::json a = nlohmann::json::parse(ModelConfigToJson(stored));
      const nlohmann::json b = nlohmann::json::parse(ModelConfigToJson(model_->config()));
      std::string differ;
      for (auto it = a.begin(); it != a.end(); ++it)
        if (!b.contains(it.key()) || b.at(it.key()) != it.value()) differ += (differ.empty() ? "" : ", ") + it.key();
      throw ModelLoad(file + ": the training state is of model config '" + stored.name +
                      "', not of the model being trained ('" + model_->config().name +
                      "'; fields that differ: " + differ + ")");
    }
    const int64_t stage = archive.meta.value("stage", int64_t{1});
    if (stage != options_.stage)
      throw ModelLoad(file + ": the training state is of stage " + std::to_string(stage) + ", not of stage " +
                      std::to_string(options_.stage) +
                      (stage == 1 ? std::string(" (to start stage II from stage-I weights, train in a new folder "
                                                "with --init-weights RUN/model.ckpt)")
                                  : std::string(" (continue it with --stage 2)")));
    torch::NoGradGuard no_grad;
    auto copy = [&](const std::string& name, torch::Tensor& dst) {
      const torch::Tensor& src = archive.Get(name, file);
      if (src.sizes() != dst.sizes() || src.scalar_type() != dst.scalar_type())
        throw ModelLoad(file + ": tensor '" + name + "' does not match the model");
      dst.copy_(src);
    };
    for (auto& item : model_->named_parameters(true)) copy("w/" + item.key(), item.value());
    for (auto& item : model_->named_buffers(true)) copy("w/" + item.key(), item.value());
    RestoreAdamMoments(archive, file, names_, archive.meta.at("param_steps"), param_steps_, exp_avg_, exp_avg_sq_,
                       "m/", "v/", device_, "optimiser");
    if (!disc_.is_empty()) {
      for (auto& item : disc_->named_parameters(true)) copy("d/" + item.key(), item.value());
      for (auto& item : disc_->named_buffers(true)) copy("d/" + item.key(), item.value());
      RestoreAdamMoments(archive, file, d_names_, archive.meta.at("d_param_steps"), d_param_steps_, d_exp_avg_,
                         d_exp_avg_sq_, "dm/", "dv/", device_, "discriminator");
    }
    sr_trained_before_ = archive.meta.value("sr_trained_before", false);
    step_ = archive.meta.at("step").get<int64_t>();
    skipped_ = archive.meta.at("skipped").get<int64_t>();
    bad_in_a_row_ = archive.meta.at("bad_in_a_row").get<int64_t>();
    {
      at::Generator cpu = DefaultGenerator(torch::kCPU);
      std::lock_guard<std::mutex> lock(cpu.mutex());
      cpu.set_state(archive.Get("rng/cpu", file));
    }
    if (!device_.is_cpu()) {
      at::Generator dev = DefaultGenerator(device_);
      std::lock_guard<std::mutex> lock(dev.mutex());
      dev.set_state(archive.Get("rng/device", file));
    }
    if (source != nullptr) source->Restore(archive.meta.at("data"));
  } catch (const nlohmann::json::exception& e) {
    throw ModelLoad(file + ": malformed training state (" + e.what() + ")");
  }
}

void StageOneTrainer::ExportWeights(const fs::path& path, const std::string& data_provenance,
                                    bool half_precision) const {
  if (!AllFinite()) throw InvalidInput(path.string() + ": not written: the weights have a non-finite value");
  CheckpointInfo info;
  info.step = step_;
  info.data_provenance = data_provenance;
  info.sr_trained = options_.stage == 2 || sr_trained_before_;
  GohaModel model = model_;
  SaveModelCheckpoint(path, model, info, half_precision);
}

void RunOptions::Validate() const {
  AVATAR_CHECK_OPTION(!out_dir.empty()) << "--out must name the run folder";
  AVATAR_CHECK_OPTION(steps >= 0) << "--steps must be >= 0";
  AVATAR_CHECK_OPTION(hours >= 0 && std::isfinite(hours)) << "--hours must be >= 0";
  AVATAR_CHECK_OPTION(checkpoint_minutes > 0) << "checkpoint_minutes must be > 0";
  AVATAR_CHECK_OPTION(checkpoint_steps >= 0) << "checkpoint_steps must be >= 0";
  AVATAR_CHECK_OPTION(sample_every >= 0) << "sample_every must be >= 0";
}

fs::path StatePath(const fs::path& out_dir) { return out_dir / "state.ckpt"; }
fs::path LogPath(const fs::path& out_dir) { return out_dir / "train.jsonl"; }

int64_t TruncateLog(const fs::path& log, int64_t first_step) {
  if (!fs::exists(log)) return 0;
  std::ifstream in(log, std::ios::binary);
  if (!in) throw Io(log.string() + ": cannot read the training log");
  std::string kept, line;
  int64_t dropped = 0;
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    bool keep = false;
    try {
      const nlohmann::json j = nlohmann::json::parse(line);
      keep = j.is_object() && (!j.contains("step") || !j.at("step").is_number_integer() ||
                               j.at("step").get<int64_t>() < first_step);
    } catch (const nlohmann::json::exception&) {
      keep = false;  // a line cut short (killed while writing)
    }
    if (keep) {
      kept += line;
      kept += '\n';
    } else {
      ++dropped;
    }
  }
  in.close();
  if (dropped > 0) WriteBytesAtomically(log, kept);
  return dropped;
}

namespace {

// The first `n` pairs of a batch (copies).
TrainBatch FirstPairs(const TrainBatch& b, int64_t n) {
  n = std::min(n, b.size());
  return b.Map([n](const torch::Tensor& t) { return t.narrow(0, 0, n).clone(); });
}

// [-1,1] renders -> CPU float in [0,1].
StageOneTrainer::Renders ForDisplay(const StageOneTrainer::Renders& r) {
  auto show = [](const torch::Tensor& t) {
    return t.defined() ? ((t.detach().to(torch::kCPU, torch::kFloat32) + 1.0) * 0.5).clamp(0.0, 1.0).nan_to_num(0.0)
                       : t;
  };
  StageOneTrainer::Renders out;
  out.target = show(r.target);
  out.canonical = show(r.canonical);
  out.expression = show(r.expression);
  out.full = show(r.full);
  out.source = show(r.source);
  out.super_resolved = show(r.super_resolved);
  return out;
}

}  // namespace

RunResult RunTraining(StageOneTrainer& trainer, BatchSource& source, const RunOptions& options, RunContext& ctx) {
  options.Validate();
  // Data parallelism: every rank trains, only rank 0 writes (state, log, samples, exports).
  GradientReducer* const reducer = trainer.gradient_reducer();
  const bool lead = reducer == nullptr || reducer->rank() == 0;
  const int64_t world = reducer != nullptr ? reducer->world_size() : 1;
  std::error_code ec;
  if (lead) fs::create_directories(options.out_dir, ec);
  if (ec) throw Io(options.out_dir.string() + ": cannot create the run folder: " + ec.message());
  const fs::path state = StatePath(options.out_dir);
  if (options.resume && fs::exists(state))
    trainer.LoadState(state, &source);
  else if (!options.init_weights.empty())
    trainer.InitFromCheckpoint(options.init_weights);
  trainer.SyncFromRankZero();
  RunResult result;
  result.first_step = trainer.step();
  std::ofstream log;
  if (lead) {
    // Every step once in the log: drop what was logged at or after the step this run starts at.
    TruncateLog(LogPath(options.out_dir), result.first_step);
    log.open(LogPath(options.out_dir), std::ios::app);
    if (!log) throw Io(LogPath(options.out_dir).string() + ": cannot open the training log");
  }
  const bool progress = options.progress && lead;
  ProgressLine progress_line = ProgressLine::ForStderr();

  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  auto last_save = start;
  auto elapsed = [](Clock::time_point since) { return std::chrono::duration<double>(Clock::now() - since).count(); };
  // The source's cursor before the batch in flight (one process: a step can be cancelled).
  nlohmann::json cursor_before;
  bool cancelled_in_step = false;
  auto save = [&] {
    if (!lead) return;
    if (cancelled_in_step)
      trainer.SaveStateAt(state, cursor_before);
    else
      trainer.SaveState(state, &source);
    last_save = Clock::now();
    if (options.on_state_written) options.on_state_written(trainer.step());
  };
  // Sample renders of the first batch this call takes.
  TrainBatch sample_batch;
  int64_t last_sampled = -1;
  auto sample = [&] {
    if (!lead || !options.on_samples || sample_batch.size() == 0 || last_sampled == trainer.step()) return;
    last_sampled = trainer.step();
    options.on_samples(trainer.step(), ForDisplay(trainer.Evaluate(sample_batch)));
  };
  auto export_weights = [&] {
    if (!lead) return;
    trainer.ExportWeights(options.out_dir / "model.ckpt", options.data_provenance);
    trainer.ExportWeights(options.out_dir / "model-fp16.ckpt", options.data_provenance, /*half_precision=*/true);
  };
  double mean_step = 0.0;
  int64_t timed = 0;
  result.stopped_by = "steps";
  // A cancel inside a step (one process only), undone when this run ends however it ends.
  struct CancelScope {
    StageOneTrainer& t;
    CancelScope(StageOneTrainer& trainer, const RunContext* ctx) : t(trainer) { t.SetCancelContext(ctx); }
    ~CancelScope() { t.SetCancelContext(nullptr); }
  } cancel_scope(trainer, reducer == nullptr ? &ctx : nullptr);
  try {
    while (trainer.step() < options.steps) {
      bool out_of_time = options.hours > 0 && elapsed(start) >= options.hours * 3600.0;
      if (reducer != nullptr) {
        // The ranks stop together: at the first step any of them is out of time or cancelled.
        std::vector<double> stop = {out_of_time ? 1.0 : 0.0, ctx.IsCancelled() ? 1.0 : 0.0};
        reducer->AllMax(stop);
        out_of_time = stop[0] > 0;
        if (stop[1] > 0) ctx.RequestCancel();
      }
      if (out_of_time) {
        result.stopped_by = "hours";
        break;
      }
      ctx.ThrowIfCancelled();
      if (reducer == nullptr) cursor_before = source.State();
      const TrainBatch batch = source.Next();
      if (lead && options.on_samples && sample_batch.size() == 0) sample_batch = FirstPairs(batch, 4);
      StepResult r;
      try {
        r = trainer.Step(batch);
      } catch (const Cancelled&) {
        cancelled_in_step = true;  // Nothing of this batch was applied: the state points at it.
        throw;
      }
      ++timed;
      mean_step += (r.seconds - mean_step) / static_cast<double>(std::min<int64_t>(timed, 20));
      // Samples of the global batch (every rank's shard) per second.
      const int64_t global_batch = batch.size() * world;
      const double samples_per_s = r.seconds > 0 ? global_batch / r.seconds : 0.0;
      nlohmann::json line = {{"step", r.step},
                             {"phase", r.phase},
                             {"loss", r.loss},
                             {"terms", r.terms},
                             {"grad_norm", r.grad_norm},
                             {"lr", trainer.options().lr},
                             {"step_s", r.seconds},
                             {"samples_per_s", samples_per_s},
                             {"batch", global_batch},
                             {"skipped", r.skipped},
                             {"skipped_total", trainer.skipped_steps()}};
      if (world > 1) line["world_size"] = world;
      if (trainer.options().stage == 2) {
        line["d_loss"] = r.d_loss;
        line["d_terms"] = r.d_terms;
        line["d_grad_norm"] = r.d_grad_norm;
        line["d_lr"] = trainer.options().d_lr;
      }
      if (r.skipped) line["skip_reason"] = r.skip_reason;
      // nlohmann writes non-finite doubles as null, which keeps each line valid JSON.
      if (lead) {
        log << line.dump() << "\n";
        log.flush();
      }
      const int64_t done = trainer.step() - result.first_step, total = options.steps - result.first_step;
      double eta = mean_step * static_cast<double>(options.steps - trainer.step());
      if (options.hours > 0) eta = std::min(eta, options.hours * 3600.0 - elapsed(start));
      if (progress) {
        std::ostringstream p;
        p << "train: step " << trainer.step() << "/" << options.steps << "  " << r.phase << "  loss " << std::fixed
          << std::setprecision(4) << r.loss << "  " << std::setprecision(2) << mean_step << " s/step  "
          << std::setprecision(1) << samples_per_s << " samples/s  skipped " << trainer.skipped_steps() << "  ETA "
          << FormatDuration(eta);
        progress_line.Update(p.str());
      }
      if (trainer.bad_in_a_row() >= trainer.options().max_bad_steps) {
        if (progress) progress_line.Finish();
        save();
        throw InvalidInput("training stopped: " + std::to_string(trainer.bad_in_a_row()) +
                           " steps in a row had a non-finite loss or gradient (last: " + r.skip_reason +
                           "); the last good state is in " + state.string());
      }
      if (elapsed(last_save) >= options.checkpoint_minutes * 60.0 ||
          (options.checkpoint_steps > 0 && trainer.step() % options.checkpoint_steps == 0))
        save();
      if (options.sample_every > 0 && trainer.step() % options.sample_every == 0) sample();
      try {
        ctx.Report("train", total > 0 ? static_cast<double>(done) / static_cast<double>(total) : 1.0,
                   "step " + std::to_string(trainer.step()));
      } catch (const Cancelled&) {
        // Data parallelism: a cancel stops the ranks together, at the next step's agreement.
        if (reducer == nullptr) throw;
      }
    }
  } catch (const Cancelled&) {
    // A cancelled run keeps its work twice: the state to resume from and usable weights of the
    // last applied step (hours of training should not need a resume only to get a model).
    if (progress) progress_line.Finish();
    save();
    export_weights();
    throw;
  }
  if (progress) progress_line.Finish();
  sample();
  save();
  export_weights();
  result.last_step = trainer.step();
  result.skipped = trainer.skipped_steps();
  return result;
}

}  // namespace avatar::train
