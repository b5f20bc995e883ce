// `avatar-studio bench model`: per-stage time and achieved GFLOP/s of the GOHA network for the
// paper and lite configs, the session's cached-frame vs full-recompute ratio, the rasterizer
// against brute force, and peak memory; every ratio against baselines measured in this run.

#include <algorithm>
#include <cstdio>
#include <functional>
#include <iostream>
#include <map>
#include <sstream>

#include <opencv2/imgproc.hpp>

#include "app/cli_util.h"
#include "app/cmd_bench.h"
#include "core/model/goha_model.h"
#include "core/model/rasterize.h"
#include "core/pipeline/session.h"
#include "core/render/camera.h"
#include "core/util/error.h"
#include "core/util/threads.h"
#include "core/util/timer.h"

namespace avatar::app {

namespace {

struct BenchModelOptions {
  // Comma-separated configs: paper, lite, tiny.
  std::string configs = "paper,lite";
  // Timed runs per stage (after one warm-up); the median is reported.
  int repeats = 3;
  // Threads, data folder, verbosity.
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("configs", configs, "Comma-separated configs: paper,lite,tiny");
    v("repeats", repeats, "Timed runs per stage (median reported)");
    common.Visit(v);
  }
  void Validate() const {
    AVATAR_CHECK_OPTION(repeats >= 1 && repeats <= 50) << "--repeats must be 1..50, got " << repeats;
    common.Validate();
  }
};

// Median wall time of `fn` over `repeats` runs after one warm-up.
double MedianSeconds(int repeats, RunContext& ctx, const std::function<void()>& fn) {
  fn();
  std::vector<double> t;
  for (int i = 0; i < repeats; ++i) {
    ctx.ThrowIfCancelled();
    Timer timer;
    fn();
    t.push_back(timer.Seconds());
  }
  return Median(t);
}

// A stand-in I_exp for timing only (a shaded disk with a mouth that opens with jawOpen). The
// morphable render itself is timed by the morphable model's own benchmark.
class BenchExpressionSource : public ExpressionImageSource {
 public:
  cv::Mat Render(const Expression& expression, int size) const override {
    float jaw = 0.0f;
    for (const auto& [name, value] : expression.controls) {
      if (name == "jawOpen") jaw = value;
    }
    cv::Mat img = cv::Mat::zeros(size, size, CV_8UC3);
    cv::circle(img, cv::Point(size / 2, size / 2), size * 3 / 8, cv::Scalar(150, 160, 190), cv::FILLED);
    cv::ellipse(img, cv::Point(size / 2, size * 2 / 3), cv::Size(size / 6, 1 + static_cast<int>(jaw * size / 8)), 0, 0,
                360, cv::Scalar(30, 30, 110), cv::FILLED);
    return img;
  }
  std::vector<std::string> ControlNames() const override { return {"jawOpen"}; }
  std::string Kind() const override { return "bench"; }
  std::string Serialize() const override { return {}; }
};

face::AlignedPortrait BenchPortrait() {
  cv::Mat img(512, 512, CV_8UC3);
  cv::randu(img, cv::Scalar::all(0), cv::Scalar::all(255));
  face::AlignedPortrait p = PortraitFromAlignedImage(img);
  p.matte = cv::Mat::zeros(512, 512, CV_32FC1);
  cv::circle(p.matte, cv::Point(256, 256), 200, cv::Scalar(1.0f), cv::FILLED);
  cv::rectangle(p.eye_mouth_mask, cv::Rect(170, 190, 170, 40), cv::Scalar(255), cv::FILLED);
  return p;
}

SourceFit BenchFit() {
  SourceFit fit;
  const torch::Tensor label = render::LabelsFromCameras(render::FrontalCameras(1))[0];
  for (int i = 0; i < 25; ++i) fit.camera[i] = label[i].item<float>();
  fit.expressions = std::make_shared<BenchExpressionSource>();
  return fit;
}

void BenchSession(const std::string& config, int repeats, RunContext& ctx) {
  SessionOptions so;
  so.random_weights = true;
  so.config = config;
  Session session(so);
  RunContext quiet;
  const face::AlignedPortrait portrait = BenchPortrait();
  const SourceFit fit = BenchFit();
  // First: one reconstruct + one final frame (the peak-memory figure for the paper config).
  Timer first;
  Avatar avatar = session.ReconstructFromAnalysis(portrait, fit, quiet);
  const Frame final_frame = session.Animate(avatar, {{{"jawOpen", 0.3f}}}, ViewPose{10, -5}, Preset::kFinal);
  const double first_s = first.Seconds();
  const double rss = PeakRssMb();
  int step = 0;
  const double full = MedianSeconds(repeats, ctx, [&] {
    avatar = session.ReconstructFromAnalysis(portrait, fit, quiet);
    session.Animate(avatar, {{{"jawOpen", 0.1f + 0.01f * static_cast<float>(++step)}}}, ViewPose{}, Preset::kStandard);
  });
  double yaw = 0.0;
  const double camera_only = MedianSeconds(repeats, ctx, [&] {
    session.Animate(avatar, {{{"jawOpen", 0.5f}}}, ViewPose{yaw += 7.0, -5}, Preset::kStandard);
  });
  const double preview = MedianSeconds(repeats, ctx, [&] {
    session.Animate(avatar, {{{"jawOpen", 0.5f}}}, ViewPose{yaw += 7.0, -5}, Preset::kPreview);
  });
  const double expression = MedianSeconds(repeats, ctx, [&] {
    session.Animate(avatar, {{{"jawOpen", 0.2f + 0.01f * static_cast<float>(++step)}}}, ViewPose{yaw, -5},
                    Preset::kStandard);
  });
  const double final_s = MedianSeconds(1, ctx, [&] {
    session.Animate(avatar, {{{"jawOpen", 0.5f}}}, ViewPose{yaw += 7.0, -5}, Preset::kFinal);
  });
  std::cout << "| " << config << " | " << Fixed(first_s, 2) << " | " << Fixed(full, 3) << " | " << Fixed(expression, 3)
            << " | " << Fixed(camera_only, 3) << " | " << Fixed(preview, 3) << " | " << Fixed(final_s, 3) << " | "
            << Fixed(full / camera_only, 1) << "x | " << Fixed(full / preview, 1) << "x | " << Fixed(rss, 0) << " MB ("
            << final_frame.bgr.cols << "^2 frame) |" << std::endl;
}

void BenchStages(const std::string& config_name, int repeats, RunContext& ctx) {
  torch::InferenceMode inference;
  torch::manual_seed(0);
  const ModelConfig c = ModelConfig::FromName(config_name);
  GohaModel model(c);
  model->eval();
  const int64_t s = c.image_size, g = c.feature_size();
  const torch::Tensor image = torch::rand({1, 3, s, s}) * 2 - 1;
  const torch::Tensor six = torch::rand({1, 6, s, s});
  const render::Cameras cams = render::FrontalCameras(1);
  std::map<std::string, double> flops;
  for (const auto& e : model->Flops()) {
    const std::string key = e.module.substr(0, e.module.find('/'));
    const std::string sub = e.module.substr(e.module.find('/') + 1);
    if (e.module == "render")
      flops["render"] += e.flops;
    else if (sub == "embed2plane")
      flops[key + " head"] += e.flops;
    else if (key == "appearance")
      flops[e.module] += e.flops;
    else
      flops[key] += e.flops;
  }
  torch::Tensor feat, tc, raster;
  const torch::Tensor matte = torch::ones({1, 1, s, s});
  // Each stage is timed right after its own GEMM-peak measurement: the machine is shared, so
  // every ratio compares two figures taken seconds apart.
  struct Row {
    std::string name;
    double seconds;
    double gemm;
  };
  std::vector<Row> rows;
  const auto time_stage = [&](const std::string& name, const std::function<void()>& fn) {
    const double gemm = MeasureGemmGflops(1024, 3);
    rows.push_back({name, MedianSeconds(repeats, ctx, fn), gemm});
  };
  time_stage("E_c", [&] { feat = model->canonical_encoder->forward(image); });
  time_stage("E_c head", [&] { tc = model->canonical_head->forward(feat); });
  render::RenderOutput depth;
  time_stage("appearance/depth_render", [&] { depth = model->Render(tc, cams, static_cast<int>(g)); });
  torch::Tensor fp;
  time_stage("E_p", [&] { fp = model->appearance_encoder->forward(six); });
  const render::Rays rays = render::GenerateRays(cams, g);
  const torch::Tensor points = rays.origins + depth.depth.reshape({1, g * g, 1}) * rays.directions;
  const torch::Tensor mask = torch::ones({1, g * g}, torch::kBool);
  const torch::Tensor pf = fp.flatten(2).transpose(1, 2).contiguous();
  time_stage("appearance/rasterization", [&] { raster = RasterizePointFeatures(points, mask, pf, g, 1.0); });
  time_stage("appearance/upsamplers", [&] {
    for (int p = 0; p < 3; ++p) model->upsamplers[p]->forward(raster.select(1, p));
  });
  time_stage("E_e", [&] { feat = model->expression_encoder->forward(image); });
  time_stage("E_e head", [&] { model->expression_head->forward(feat); });
  render::RenderOutput out;
  time_stage("render", [&] { out = model->Render(tc, cams); });
  double sr_flops = 0;
  for (const auto& e : model->super_resolution->Flops()) sr_flops += e.flops;
  flops["SR"] = sr_flops;
  time_stage("SR", [&] { model->SuperResolve(out.rgb); });
  double total_t = 0, total_f = 0, gemm_sum = 0;
  for (const auto& row : rows) {
    const double f = flops.count(row.name) ? flops[row.name] : 0.0;
    const double t = row.seconds;
    total_t += t;
    total_f += f;
    gemm_sum += row.gemm * t;
    std::cout << "| " << config_name << " | " << row.name << " | " << Fixed(t * 1e3, 1) << " | " << Fixed(f / 1e9, 2)
              << " | " << (f > 0 ? Fixed(f / t / 1e9, 1) : std::string("-")) << " | " << Fixed(row.gemm, 0) << " | "
              << (f > 0 ? Fixed(100.0 * f / t / 1e9 / row.gemm, 0) + "%" : std::string("-")) << " |" << std::endl;
  }
  const double gemm_mean = gemm_sum / total_t;  // time-weighted
  std::cout << "| " << config_name << " | **all stages** | " << Fixed(total_t * 1e3, 1) << " | "
            << Fixed(total_f / 1e9, 2) << " | " << Fixed(total_f / total_t / 1e9, 1) << " | " << Fixed(gemm_mean, 0)
            << " | " << Fixed(100.0 * total_f / total_t / 1e9 / gemm_mean, 0) << "% |" << std::endl;
}

void BenchRasterizer(int repeats, RunContext& ctx) {
  torch::manual_seed(1);
  const int64_t grid = 128, n = grid * grid;
  // Points of a lifted depth map look like a surface: a noisy sphere cap in the unit box.
  const torch::Tensor dir =
      torch::nn::functional::normalize(torch::randn({n, 3}), torch::nn::functional::NormalizeFuncOptions().dim(1));
  const torch::Tensor pts = (dir * 0.35 * (1 + 0.05 * torch::randn({n, 1}))).unsqueeze(0);
  const torch::Tensor feats = torch::randn({1, n, 256});
  const torch::Tensor mask = torch::ones({1, n}, torch::kBool);
  torch::InferenceMode inference;
  const double kd =
      MedianSeconds(std::max(repeats, 5), ctx, [&] { RasterizePointFeatures(pts, mask, feats, grid, 1.0); });
  const torch::Tensor xy = pts[0].narrow(1, 0, 2) * 2.0;
  const double search = MedianSeconds(repeats, ctx, [&] { NearestPointIndices(xy, grid); });
  Timer brute_timer;
  const auto brute = NearestPointIndicesBruteForce(xy, grid);
  const double brute_s = brute_timer.Seconds();
  const bool same = brute == NearestPointIndices(xy, grid);
  std::cout << "Rasterization of a " << grid << "x" << grid << "-point cloud (256 features) onto three " << grid << "x"
            << grid << " grids, features gathered into [3,256,128,128]: " << Fixed(kd * 1e3, 1)
            << " ms (target <= 50 ms); one plane's k-d tree search " << Fixed(search * 1e3, 1) << " ms vs brute force "
            << Fixed(brute_s * 1e3, 0) << " ms (" << Fixed(brute_s / search, 0)
            << "x faster, identical indices: " << (same ? "yes" : "NO") << ").\n\n";
}

int RunBenchModelImpl(const BenchModelOptions& options, RunContext& ctx) {
  options.Validate();
  const auto configs = SplitList(options.configs);
  for (const auto& c : configs) ModelConfig::FromName(c);
  const int threads = ConfiguredThreads() > 0 ? ConfiguredThreads() : ConfigureThreads(options.common.threads);
  const double gemm = MeasureGemmGflops();
  std::cout << "Model benchmark: " << threads << " threads, random weights, float32, inference mode, median of "
            << options.repeats << " runs after a warm-up.\nGEMM peak (fp32 1024^3, best of 5): " << Fixed(gemm, 1)
            << " GFLOP/s\n\n"
            << std::flush;
  std::cout << "Session (synthetic I_exp; times in s): full = reconstruct + frame with a new expression; "
               "camera-only and preview reuse every plane.\n\n"
            << "| config | first reconstruct + final frame | full recompute | new expression | camera-only frame | "
               "camera-only preview | final frame (SR) | full / camera-only | full / preview | peak RSS so far |\n"
            << "|---|---|---|---|---|---|---|---|---|---|\n";
  for (const auto& c : configs) BenchSession(c, options.repeats, ctx);
  std::cout << "\n";
  BenchRasterizer(options.repeats, ctx);
  std::cout << "Stages (GEMM peak measured right before each stage, best of 3):\n\n"
            << "| config | stage | time (ms) | GFLOPs | GFLOP/s | GEMM peak (GFLOP/s) | of GEMM peak |\n"
            << "|---|---|---|---|---|---|---|\n";
  for (const auto& c : configs) BenchStages(c, options.repeats, ctx);
  std::cout << "\nGEMM peak after the run: " << Fixed(MeasureGemmGflops(), 1)
            << " GFLOP/s. FLOPs are analytic (see `avatar-studio inspect`); render FLOPs count only the decoder MLP.\n";
  return kExitOk;
}

int RunBenchModel(const std::vector<std::string>& args) {
  return RunBenchSubject<BenchModelOptions>(
      args, "model",
      "Times every stage of the GOHA network (random weights), the session's cached frames\n"
      "against a full recompute, the rasterizer against brute force, and peak memory.",
      RunBenchModelImpl);
}

}  // namespace

AVATAR_REGISTER_BENCH_SUBJECT("model",
                              "GOHA network: per-stage time and GFLOP/s vs GEMM peak, cached vs full frames, "
                              "rasterizer, peak memory",
                              RunBenchModel);

}  // namespace avatar::app
