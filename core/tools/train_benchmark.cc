#include "core/tools/train_benchmark.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <memory>
#include <sstream>

#include <nlohmann/json.hpp>

#include "core/io/atomic_file.h"
#include "core/model/goha_model.h"
#include "core/model/super_resolution.h"
#include "core/tools/benchmarks.h"
#include "core/render/camera.h"
#include "core/render/renderer.h"
#include "core/train/losses.h"
#include "core/train/perceptual.h"
#include "core/train/trainer.h"
#include "core/util/error.h"
#include "core/util/threads.h"
#include "core/util/timer.h"

namespace avatar {
namespace {

// ---------------------------------------------------------------------------------------------
// Memory. Linux keeps a resettable high-water mark (VmHWM; writing 5 to /proc/self/clear_refs
// resets it to the current RSS), so each case gets its own peak. Without it the growth of
// getrusage's ru_maxrss (the process's lifetime peak) is reported instead.

double StatusMb(const std::string& key) {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind(key + ":", 0) == 0) {
      std::istringstream fields(line.substr(key.size() + 1));
      double kb = 0;
      fields >> kb;
      return kb / 1024.0;
    }
  }
  return -1.0;
}

bool ResetPeakRss() {
  std::ofstream out("/proc/self/clear_refs");
  if (!out) return false;
  out << "5";
  out.flush();
  return static_cast<bool>(out);
}

// ---------------------------------------------------------------------------------------------
// Synthetic batches: an ellipse "head" with smooth colour ramps and a little noise on a black
// background, a mouth band for the eye/mouth mask, a frontal source camera and a target camera
// turned by a few degrees. Each call shifts the pattern so that no two batches are equal.

class BenchBatchSource : public train::BatchSource {
 public:
  BenchBatchSource(int64_t image_size, int64_t batch) : size_(image_size), batch_(batch) {}

  train::TrainBatch Next() override {
    std::vector<train::TrainSample> samples;
    for (int64_t i = 0; i < batch_; ++i) samples.push_back(Sample(cursor_ * batch_ + i));
    ++cursor_;
    return train::Collate(samples);
  }
  nlohmann::json State() const override { return {{"cursor", cursor_}}; }
  void Restore(const nlohmann::json& state) override { cursor_ = state.at("cursor").get<int64_t>(); }

 private:
  train::TrainSample Sample(int64_t index) const {
    const int64_t s = size_;
    const double phase = 0.1 * static_cast<double>(index % 7);
    const torch::Tensor v = torch::linspace(-1, 1, s).view({1, s, 1}).expand({1, s, s});
    const torch::Tensor u = torch::linspace(-1, 1, s).view({1, 1, s}).expand({1, s, s});
    const torch::Tensor head = ((u * u) / 0.42 + (v * v) / 0.55 < 1.0).to(torch::kFloat32);
    const torch::Tensor mouth = ((v - 0.35).abs() < 0.06) * ((u.abs()) < 0.25);
    const auto picture = [&](double a, double b) {
      const torch::Tensor rgb = torch::cat({0.5 + 0.3 * torch::sin(3 * u + a), 0.2 + 0.3 * torch::cos(2 * v + b),
                                            0.1 * u - 0.2 + 0.05 * torch::randn({1, s, s})},
                                           0)
                                    .clamp(-1, 1);
      return rgb * head + (head - 1);  // black (-1) outside the matte
    };
    train::TrainSample t;
    t.source = picture(phase, 0.0);
    t.source_matte = head;
    t.source_eye_mouth = mouth.to(torch::kFloat32);
    t.source_label = render::LabelsFromCameras(render::FrontalCameras(1))[0];
    render::ViewPose pose;  // The camera to the side and 3 degrees above.
    pose.yaw = 8.0 + 4.0 * static_cast<double>(index % 3);
    pose.pitch = -3.0;
    const render::Cameras target_cam{render::OrbitCam2World(pose).unsqueeze(0),
                                     render::DefaultIntrinsics().unsqueeze(0)};
    t.target_label = render::LabelsFromCameras(target_cam)[0];
    t.target = picture(phase + 0.3, 0.2);
    t.target_matte = head;
    t.expression_image = picture(phase, 0.5);
    t.neutral_image = t.source.clone();
    t.neutral_mask = head;
    t.target_expression = torch::zeros({8});
    t.kind = train::PairKind::kSynthetic;
    t.identity = index % 5;
    return t;
  }

  int64_t size_;
  int64_t batch_;
  int64_t cursor_ = 0;
};

// ---------------------------------------------------------------------------------------------
// The forward half of StageOneTrainer::Step: the trainer's own LossTerms at its current step
// (the step's terms, with gradients recorded) -> their sum. The graph is dropped by the caller
// without a backward pass.
torch::Tensor ForwardLosses(train::StageOneTrainer& trainer, const train::TrainBatch& batch) {
  trainer.model()->train();
  torch::Tensor total;
  for (const auto& [name, t] : trainer.LossTerms(batch.To(trainer.device()), trainer.step())) {
    total = total.defined() ? total + t : t;
  }
  return total;
}

TrainBenchmarkCase RunCase(const std::string& config_name, int64_t batch, const TrainBenchmarkOptions& options,
                   const train::PerceptualFn& perceptual, bool peak_resettable, RunContext& ctx) {
  TrainBenchmarkCase r;
  r.config = config_name;
  r.batch = batch;
  // This case's baseline: the GEMM rate right before it (the machine is shared).
  r.gemm_gflops = MeasureGemmGflops(kTrainBenchmarkGemmSize, 3);
  const double rss_start = peak_resettable ? StatusMb("VmRSS") : PeakRssMb();
  if (peak_resettable) ResetPeakRss();
  {
    torch::manual_seed(1);
    const ModelConfig config = ModelConfig::FromName(config_name);
    GohaModelOptions model_options;
    model_options.pretrained = false;  // random backbones: the timing does not depend on the weights
    model_options.data_dir = options.data_dir;
    train::TrainerOptions to;  // the training defaults: every term from step 0
    train::StageOneTrainer trainer(GohaModel(config, model_options), to, perceptual);
    BenchBatchSource source(config.image_size, batch);
    for (int i = 0; i < options.warmup; ++i) {
      ctx.ThrowIfCancelled();
      const train::StepResult s = trainer.Step(source.Next());
      r.skipped += s.skipped ? 1 : 0;
    }
    for (int i = 0; i < options.steps; ++i) {
      ctx.ThrowIfCancelled();
      const train::TrainBatch b = source.Next();
      // The step then draws the same random numbers (sample jitter, TV points) as the forward
      // pass, so both compute the same loss: a check that the forward pass is the step's.
      at::Generator generator = at::globalContext().defaultGenerator(trainer.device());
      const torch::Tensor rng_state = generator.get_state();
      double forward_loss = 0;
      {
        Timer timer;
        const torch::Tensor loss = ForwardLosses(trainer, b);
        forward_loss = loss.item<double>();  // waits for the value, as the step does
        r.forward_s.push_back(timer.Seconds());
        AVATAR_CHECK(std::isfinite(forward_loss))
            << "bench train: the forward pass of " << config_name << " gave a non-finite loss";
      }
      ctx.ThrowIfCancelled();
      generator.set_state(rng_state);
      Timer timer;
      const train::StepResult s = trainer.Step(b);
      r.step_s.push_back(timer.Seconds());
      r.skipped += s.skipped ? 1 : 0;
      r.last_loss = s.loss;
      r.loss_rel_diff = std::max(r.loss_rel_diff, std::abs(forward_loss - s.loss) / std::max(std::abs(s.loss), 1e-12));
    }
  }
  r.peak_rss_mb = peak_resettable ? StatusMb("VmHWM") : PeakRssMb();
  r.rss_growth_mb = std::max(0.0, r.peak_rss_mb - rss_start);
  r.step = Median(r.step_s);
  r.forward = Median(r.forward_s);
  r.backward = r.step - r.forward;
  return r;
}

train::PerceptualFn MakePerceptual(const TrainBenchmarkOptions& options) {
  if (options.perceptual == "pyramid") {
    return [](const torch::Tensor& a, const torch::Tensor& b) { return train::PyramidL1Distance(a, b); };
  }
  if (options.perceptual != "mobilenet") return {};
  PerceptualOptions po;
  po.data_dir = options.data_dir;
  auto net = std::make_shared<PerceptualLoss>(po);
  // As `train`: MobileNetV2 wants >= 32 px, smaller renders are upsampled for this term only.
  return [net](const torch::Tensor& a, const torch::Tensor& b) {
    if (a.size(2) >= 32) return net->Distance(a, b);
    return net->Distance(ResizeBilinear(a, 32, 32), ResizeBilinear(b, 32, 32));
  };
}

void WriteJson(const TrainBenchmarkOptions& options, const TrainBenchmarkReport& report) {
  nlohmann::json j;
  j["threads"] = report.threads;
  j["perceptual"] = options.perceptual;
  j["steps"] = options.steps;
  j["warmup"] = options.warmup;
  j["gemm_gflops_before"] = report.gemm_before;
  j["gemm_gflops_after"] = report.gemm_after;
  j["rss_method"] = report.peak_resettable ? "VmHWM reset per case" : "ru_maxrss";
  j["reference_step_s"] = report.reference_step;
  nlohmann::json rows = nlohmann::json::array();
  for (const auto& r : report.cases) {
    nlohmann::json row;
    row["config"] = r.config;
    row["batch"] = r.batch;
    row["reference_only"] = r.reference_only;
    row["step_s"] = r.step;
    row["forward_s"] = r.forward;
    row["backward_s"] = r.backward;
    row["samples_per_s"] = static_cast<double>(r.batch) / r.step;
    row["peak_rss_mb"] = r.peak_rss_mb;
    row["rss_growth_mb"] = r.rss_growth_mb;
    row["step_ratio_to_tiny_b1"] = r.step / report.reference_step;
    row["gemm_gflops"] = r.gemm_gflops;
    row["step_ratio_to_gemm"] = r.StepOverGemm();
    row["step_times_s"] = r.step_s;
    row["forward_times_s"] = r.forward_s;
    row["last_loss"] = r.last_loss;
    row["forward_loss_rel_diff"] = r.loss_rel_diff;
    row["skipped_steps"] = r.skipped;
    rows.push_back(row);
  }
  j["rows"] = rows;
  WriteBytesAtomically(options.json, j.dump(2) + "\n");
}

}  // namespace

double TrainBenchmarkCase::StepOverGemm() const {
  const double n = static_cast<double>(kTrainBenchmarkGemmSize);
  return step / (2.0 * n * n * n / (gemm_gflops * 1e9));
}

void TrainBenchmarkOptions::Validate() const {
  AVATAR_CHECK_OPTION(!configs.empty()) << "--configs is empty";
  for (const auto& name : configs) {
    AVATAR_CHECK_OPTION(name == "tiny" || name == "cpu" || name == "lite" || name == "paper")
        << "unknown config '" << name << "' in --configs (tiny, cpu, lite, paper)";
  }
  AVATAR_CHECK_OPTION(!batches.empty()) << "--batches is empty";
  for (const int64_t b : batches) {
    AVATAR_CHECK_OPTION(b >= 1 && b <= 64) << "--batches takes comma-separated integers 1..64, got '" << b << "'";
  }
  AVATAR_CHECK_OPTION(steps >= 1 && steps <= 100) << "--steps must be 1..100, got " << steps;
  AVATAR_CHECK_OPTION(warmup >= 0 && warmup <= 20) << "--warmup must be 0..20, got " << warmup;
  AVATAR_CHECK_OPTION(perceptual == "mobilenet" || perceptual == "pyramid" || perceptual == "none")
      << "--perceptual must be mobilenet, pyramid or none, got '" << perceptual << "'";
}

TrainBenchmarkReport RunTrainBenchmark(const TrainBenchmarkOptions& options, int threads, RunContext& ctx,
                                       const TrainBenchmarkListener& listener) {
  options.Validate();
  TrainBenchmarkReport report;
  report.threads = ConfiguredThreads() > 0 ? ConfiguredThreads() : ConfigureThreads(threads);
  const train::PerceptualFn perceptual = MakePerceptual(options);
  report.peak_resettable = ResetPeakRss() && StatusMb("VmHWM") > 0;

  // Every ratio is to the tiny batch-1 step of this run, so that case runs first; it is added
  // (marked "reference") when not asked for.
  std::vector<std::pair<std::string, int64_t>> cases;
  for (const auto& c : options.configs)
    for (const int64_t b : options.batches) cases.emplace_back(c, b);
  const std::pair<std::string, int64_t> reference_case("tiny", 1);
  const auto found = std::find(cases.begin(), cases.end(), reference_case);
  const bool reference_asked = found != cases.end();
  if (reference_asked) cases.erase(found);
  cases.insert(cases.begin(), reference_case);

  report.gemm_before = MeasureGemmGflops(kTrainBenchmarkGemmSize, 5);
  if (listener.started) listener.started(report);
  for (size_t i = 0; i < cases.size(); ++i) {
    ctx.ThrowIfCancelled();
    TrainBenchmarkCase r = RunCase(cases[i].first, cases[i].second, options, perceptual, report.peak_resettable, ctx);
    r.reference_only = i == 0 && !reference_asked;
    if (i == 0) report.reference_step = r.step;
    report.worst_loss_rel_diff = std::max(report.worst_loss_rel_diff, r.loss_rel_diff);
    report.cases.push_back(std::move(r));
    if (listener.measured) listener.measured(report.cases.back(), report.reference_step);
  }
  report.gemm_after = MeasureGemmGflops(kTrainBenchmarkGemmSize, 5);
  if (!options.json.empty()) {
    WriteJson(options, report);
    report.json_path = options.json;
  }
  return report;
}

}  // namespace avatar
