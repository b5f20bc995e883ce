#include "core/pipeline/refine.h"

#include <chrono>
#include <cmath>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <sstream>

#include <ATen/CPUGeneratorImpl.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>
#include <torch/torch.h>

#include "core/morphable/mesh_renderer.h"
#include "core/pipeline/session_access.h"
#include "core/pipeline/source_analysis.h"
#include "core/render/camera.h"
#include "core/render/renderer.h"
#include "core/train/losses.h"
#include "core/train/perceptual.h"
#include "core/util/error.h"

namespace avatar {

namespace {

namespace F = torch::nn::functional;

bool Finite(double v) { return std::isfinite(v); }

// One PerceptualLoss per data folder for the process (loading MobileNetV2 takes a moment).
std::shared_ptr<const PerceptualLoss> SharedPerceptual(const std::string& data_dir, const torch::Device& device) {
  static std::mutex mutex;
  static std::map<std::string, std::shared_ptr<PerceptualLoss>> cache;
  std::lock_guard<std::mutex> lock(mutex);
  const std::string key = data_dir + "|" + device.str();
  auto it = cache.find(key);
  if (it != cache.end()) return it->second;
  PerceptualOptions po;
  po.data_dir = data_dir;
  auto loss = std::make_shared<PerceptualLoss>(po);
  loss->To(device);
  cache.emplace(key, loss);
  return loss;
}

// Float [0,1] BGR (or 8-bit) -> BGR8.
cv::Mat ToBgr8(const cv::Mat& m, const char* what) {
  AVATAR_CHECK_INPUT(m.channels() == 3 && (m.depth() == CV_8U || m.depth() == CV_32F))
      << what << " must be a 3-channel 8-bit or float image";
  if (m.depth() == CV_8U) return m;
  cv::Mat out;
  m.convertTo(out, CV_8UC3, 255.0);
  return out;
}

// PSNR (dB) of [1,3,R,R] images in [-1,1] over the mask [1,1,R,R].
double MaskedPsnr(const torch::Tensor& a, const torch::Tensor& b, const torch::Tensor& mask) {
  const torch::Tensor d = ((a.detach().to(torch::kFloat64) - b.detach().to(torch::kFloat64)) / 2.0).pow(2);
  const torch::Tensor m = mask.detach().to(torch::kFloat64);
  const double mse = (d * m).sum().item<double>() / (3.0 * m.sum().item<double>() + 1e-12);
  return 10.0 * std::log10(1.0 / std::max(mse, 1e-20));
}

// Everything one refinement needs, on the model's device.
struct Problem {
  mutable GohaModel model{nullptr};  // forward passes only
  render::Cameras cameras;
  int resolution = 0;
  torch::Tensor target;         // matted source [1,3,R,R]
  torch::Tensor matte;          // [1,1,R,R]
  torch::Tensor neutral_image;  // [1,3,S,S] or undefined
  torch::Tensor neutral_mask;   // [1,1,S,S]
  torch::Tensor expression;     // T_e0 (zeros when the avatar has no expression source)

  Problem(const Session& session, const Avatar& avatar, const RefineTarget& t, int res) {
    SessionAccess::CheckAvatar(session, avatar);
    model = SessionAccess::Model(session);
    const ModelConfig& c = model->config();
    resolution = res > 0 ? res : c.render_size;
    const torch::Tensor planes = SessionAccess::Canonical(avatar);
    const torch::Device device = planes.device();
    torch::NoGradGuard no_grad;
    const std::array<float, 25> label = avatar.SourceCamera();
    for (float v : label) AVATAR_CHECK_INPUT(std::isfinite(v)) << "source camera label has non-finite values";
    const torch::Tensor lt = torch::from_blob(const_cast<float*>(label.data()), {1, 25}, torch::kFloat32).clone();
    cameras = render::CamerasFromLabels(lt.to(device));
    AVATAR_CHECK_INPUT(!t.image.empty()) << "refinement target has no image";
    const int s = c.image_size;
    const torch::Tensor image = SessionAccess::ImageTensor(ToBgr8(t.image, "refinement image"), s, "refinement image");
    const torch::Tensor m = SessionAccess::MaskTensor(t.matte, s, 1.0f, "refinement matte");
    target = train::ResizeTo(train::Matte(image, m), resolution).to(device);
    matte = train::ResizeTo(m, resolution).to(device);
    if (!t.neutral_image.empty()) {
      AVATAR_CHECK_INPUT(!t.neutral_mask.empty()) << "refinement target: I_neu needs its mask M_neu";
      neutral_image =
          SessionAccess::ImageTensor(ToBgr8(t.neutral_image, "neutral image"), s, "neutral image").to(device);
      neutral_mask = SessionAccess::MaskTensor(t.neutral_mask, s, 0.0f, "neutral mask").to(device);
    }
    expression = SessionAccess::ExpressionPlanes(session, avatar, Expression{});
    if (!expression.defined()) expression = torch::zeros_like(planes);
    expression = expression.clone().to(device);  // a plain (non-inference) tensor
  }

  torch::Tensor RenderRgb(const torch::Tensor& planes) const {
    return model->Render(planes, cameras, resolution, /*deterministic=*/true).rgb;
  }
};

// Perceptual distance at >= 32 px (MobileNetV2's smallest input).
torch::Tensor PerceptualAt32(const PerceptualLoss& loss, const torch::Tensor& a, const torch::Tensor& b) {
  if (a.size(2) >= 32) return loss.Distance(a, b);
  const auto up = F::InterpolateFuncOptions().size(std::vector<int64_t>{32, 32}).mode(torch::kBilinear).align_corners(false);
  return loss.Distance(F::interpolate(a, up), F::interpolate(b, up));
}

}  // namespace

void RefineOptions::Validate() const {
  AVATAR_CHECK_OPTION(steps >= 0 && steps <= 1000000) << "--refine-steps must be 0..1000000, got " << steps;
  AVATAR_CHECK_OPTION(Finite(seconds) && seconds >= 0) << "--refine-seconds must be >= 0, got " << seconds;
  AVATAR_CHECK_OPTION(Finite(lr) && lr > 0 && lr <= 10) << "--refine-lr must be in (0, 10], got " << lr;
  for (const auto& [name, w] : {std::pair<const char*, double>{"--refine-l1", l1_weight},
                                {"--refine-perceptual", perceptual_weight},
                                {"--refine-neutral", neutral_weight},
                                {"--refine-tv", tv_weight},
                                {"--refine-prior", prior_weight}}) {
    AVATAR_CHECK_OPTION(Finite(w) && w >= 0 && w <= 1e6) << name << " must be in [0, 1e6], got " << w;
  }
  AVATAR_CHECK_OPTION(l1_weight > 0 || perceptual_weight > 0)
      << "refinement needs a source term: --refine-l1 or --refine-perceptual must be > 0";
  AVATAR_CHECK_OPTION(Finite(grad_clip) && grad_clip >= 0) << "refinement grad_clip must be >= 0";
  AVATAR_CHECK_OPTION(tv_points >= 1 && tv_points <= 1000000) << "refinement tv_points must be 1..1000000";
  AVATAR_CHECK_OPTION(seed >= 0) << "--refine-seed must be >= 0, got " << seed;
  AVATAR_CHECK_OPTION(resolution == 0 || (resolution >= 8 && resolution <= 1024))
      << "refinement resolution must be 0 (the model's) or 8..1024, got " << resolution;
}

RefineTarget RefineTargetFromAnalysis(const SourceAnalysis& analysis, int size) {
  AVATAR_CHECK_INPUT(size >= 16) << "refinement target size must be >= 16";
  RefineTarget t;
  t.image = analysis.portrait.image;
  t.matte = analysis.portrait.matte;
  if (analysis.model != nullptr) {
    const morphable::RenderResult neu =
        morphable::RenderNeutral(*analysis.model, analysis.morphable_fit, analysis.texture, cv::Size(size, size));
    t.neutral_image = neu.image;
    t.neutral_mask = neu.mask;
  }
  return t;
}

double SourceViewPsnr(const Session& session, const Avatar& avatar, const RefineTarget& target) {
  try {
    torch::InferenceMode inference;
    const Problem p(session, avatar, target, 0);
    const torch::Tensor planes = SessionAccess::Canonical(avatar) + SessionAccess::Appearance(avatar) + p.expression;
    return MaskedPsnr(p.RenderRgb(planes), p.target, p.matte);
  } catch (...) {
    RethrowAsAvatarError("refine");
  }
}

RefineResult RefineAvatar(const Session& session, const Avatar& avatar, const SourceAnalysis& analysis,
                          const RefineOptions& options, RunContext& ctx) {
  return RefineAvatar(session, avatar, RefineTargetFromAnalysis(analysis), options, ctx);
}

RefineResult RefineAvatar(const Session& session, const Avatar& avatar, const RefineTarget& target,
                          const RefineOptions& options, RunContext& ctx) {
  options.Validate();
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  auto elapsed = [&] { return std::chrono::duration<double>(Clock::now() - start).count(); };
  try {
    c10::InferenceMode no_inference(false);
    torch::AutoGradMode grad_on(true);
    ctx.Report("refine", 0.0, "preparing");
    const Problem p(session, avatar, target, options.resolution);
    const torch::Device device = p.target.device();
    std::shared_ptr<const PerceptualLoss> perceptual;
    if (options.perceptual_weight > 0) perceptual = SharedPerceptual(options.data_dir, device);
    const double box_warp = p.model->RenderOptionsFor(p.resolution).box_warp;
    const bool neutral = options.neutral_weight > 0 && p.neutral_image.defined();

    const torch::Tensor tc0 = SessionAccess::Canonical(avatar).clone();
    const torch::Tensor tp0 = SessionAccess::Appearance(avatar).clone();
    torch::Tensor tc = tc0.clone().requires_grad_(true);
    torch::Tensor tp = tp0.clone().requires_grad_(true);
    torch::optim::Adam adam({tc, tp}, torch::optim::AdamOptions(options.lr));
    at::Generator gen = at::detail::createCPUGenerator(static_cast<uint64_t>(options.seed));

    // The deterministic terms of the objective (source, neutral, prior); TV is added for the
    // gradient only (its points are random). Each term is its own forward and backward pass, so
    // that cancellation is checked at least every render-sized piece of work.
    auto source_term = [&](const torch::Tensor& c, const torch::Tensor& a) {
      const torch::Tensor rgb = p.RenderRgb(c + a + p.expression);
      torch::Tensor loss = options.l1_weight * train::L1Distance(rgb, p.target).mean();
      if (perceptual) loss = loss + options.perceptual_weight * PerceptualAt32(*perceptual, rgb, p.target).mean();
      return std::make_pair(loss, rgb);
    };
    auto neutral_term = [&](const torch::Tensor& c) {
      return options.neutral_weight * train::NeutralLoss(p.RenderRgb(c), p.neutral_image, p.neutral_mask, {}).mean();
    };
    auto prior_term = [&](const torch::Tensor& c, const torch::Tensor& a) {
      return options.prior_weight * ((c - tc0).pow(2).mean() + (a - tp0).pow(2).mean());
    };
    auto objective = [&](const torch::Tensor& c, const torch::Tensor& a) {
      auto [loss, rgb] = source_term(c, a);
      if (neutral) loss = loss + neutral_term(c);
      if (options.prior_weight > 0) loss = loss + prior_term(c, a);
      return std::make_pair(loss, rgb);
    };

    RefineResult result;
    torch::Tensor best_c = tc0, best_a = tp0;
    double best_loss = std::numeric_limits<double>::infinity();
    torch::Tensor best_rgb;
    auto consider = [&](double loss, const torch::Tensor& rgb, int step) {
      if (!(loss < best_loss)) return;
      best_loss = loss;
      best_c = tc.detach().clone();
      best_a = tp.detach().clone();
      best_rgb = rgb.detach();
      result.best_step = step;
    };
    const int max_steps =
        options.steps > 0 ? options.steps : (options.seconds > 0 ? std::numeric_limits<int>::max() : 0);
    result.stopped_by = "steps";
    for (int step = 0;; ++step) {
      ctx.ThrowIfCancelled();
      const bool out_of_steps = step >= max_steps;
      const bool out_of_time = options.seconds > 0 && elapsed() >= options.seconds;
      const bool last = out_of_steps || out_of_time;
      if (last && !out_of_steps) result.stopped_by = "seconds";
      if (last) {
        // The planes of the last update: evaluated once without a gradient.
        torch::NoGradGuard no_grad;
        const auto [loss, rgb] = objective(tc, tp);
        const double v = loss.item<double>();
        if (step == 0) result.loss_before = v;
        if (Finite(v)) consider(v, rgb, step);
        break;
      }
      std::vector<torch::Tensor> grads(2);
      auto accumulate = [&](const torch::Tensor& loss) {
        ctx.ThrowIfCancelled();  // between the forward and the backward pass
        const std::vector<torch::Tensor> g =
            torch::autograd::grad({loss}, {tc, tp}, {}, /*retain_graph=*/false, /*create_graph=*/false,
                                  /*allow_unused=*/true);
        for (size_t i = 0; i < 2; ++i)
          if (g[i].defined()) grads[i] = grads[i].defined() ? grads[i] + g[i] : g[i];
        ctx.ThrowIfCancelled();
      };
      auto [loss, rgb] = source_term(tc, tp);
      double v = loss.item<double>();
      accumulate(loss);
      if (neutral) {
        const torch::Tensor n = neutral_term(tc);
        v += n.item<double>();
        accumulate(n);
      }
      if (options.prior_weight > 0) {
        const torch::Tensor pr = prior_term(tc, tp);
        v += pr.item<double>();
        accumulate(pr);
      }
      if (step == 0) result.loss_before = v;
      if (!Finite(v)) {
        result.stopped_by = "non-finite";
        break;
      }
      consider(v, rgb, step);
      if (options.tv_weight > 0) {
        ctx.ThrowIfCancelled();
        auto decoder = [&p](const torch::Tensor& f) { return p.model->decoder->forward(f); };
        const render::Field field = render::MakeTriplaneField(tc + tp + p.expression, decoder, box_warp);
        const train::DensityFn density = [&field](const torch::Tensor& x) { return field(x).raw_density; };
        const double half = box_warp / 2.0;
        const torch::Tensor u = torch::rand({1, options.tv_points, 3}, gen, torch::kFloat32);
        const torch::Tensor n = torch::randn({1, options.tv_points, 3}, gen, torch::kFloat32);
        const torch::Tensor points = ((u * 2.0 - 1.0) * half).to(device);
        const torch::Tensor perturbed = points + n.to(device) * (0.004 * half);
        accumulate(options.tv_weight * train::DensityTvAt(density, points, perturbed));
      }
      for (auto& g : grads)
        if (!g.defined()) g = torch::zeros_like(tc);
      double norm_sq = 0.0;
      for (const auto& g : grads) norm_sq += g.to(torch::kFloat64).pow(2).sum().item<double>();
      const double norm = std::sqrt(norm_sq);
      if (!Finite(norm)) {
        result.stopped_by = "non-finite";
        break;
      }
      const double scale = options.grad_clip > 0 && norm > options.grad_clip ? options.grad_clip / (norm + 1e-12) : 1.0;
      tc.mutable_grad() = scale == 1.0 ? grads[0] : grads[0] * scale;
      tp.mutable_grad() = scale == 1.0 ? grads[1] : grads[1] * scale;
      adam.step();
      result.steps = step + 1;
      {
        torch::NoGradGuard no_grad;
        if (!torch::isfinite(tc).all().item<bool>() || !torch::isfinite(tp).all().item<bool>()) {
          result.stopped_by = "non-finite";
          break;
        }
      }
      double fraction = options.steps > 0 ? static_cast<double>(step + 1) / options.steps : 0.0;
      if (options.seconds > 0) fraction = std::max(fraction, elapsed() / options.seconds);
      std::ostringstream msg;
      msg << "step " << (step + 1);
      if (options.steps > 0) msg << "/" << options.steps;
      msg << " loss " << v;
      ctx.Report("refine", std::min(fraction, 0.99), msg.str());
    }
    AVATAR_CHECK(best_rgb.defined()) << "refinement: the one-shot planes give a non-finite objective";
    result.loss_after = best_loss;
    {
      torch::NoGradGuard no_grad;
      const torch::Tensor rgb0 = p.RenderRgb(tc0 + tp0 + p.expression);
      result.psnr_before = MaskedPsnr(rgb0, p.target, p.matte);
      result.psnr_after = MaskedPsnr(best_rgb, p.target, p.matte);
    }
    result.seconds = elapsed();
    nlohmann::json info = {{"steps", result.steps},
                           {"best_step", result.best_step},
                           {"seconds", result.seconds},
                           {"stopped_by", result.stopped_by},
                           {"loss_before", result.loss_before},
                           {"loss_after", result.loss_after},
                           {"psnr_before", result.psnr_before},
                           {"psnr_after", result.psnr_after},
                           {"resolution", p.resolution},
                           {"lr", options.lr},
                           {"l1_weight", options.l1_weight},
                           {"perceptual_weight", options.perceptual_weight},
                           {"neutral_weight", neutral ? options.neutral_weight : 0.0},
                           {"tv_weight", options.tv_weight},
                           {"prior_weight", options.prior_weight},
                           {"seed", options.seed}};
    result.avatar = SessionAccess::WithPlanes(avatar, best_c, best_a, info.dump());
    ctx.Report("refine", 1.0, "done");
    return result;
  } catch (...) {
    RethrowAsAvatarError("refine");
  }
}

}  // namespace avatar
