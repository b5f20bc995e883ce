#include "core/tools/model_benchmark.h"

#include <map>

#include <opencv2/imgproc.hpp>

#include "core/model/goha_model.h"
#include "core/model/rasterize.h"
#include "core/tools/benchmarks.h"
#include "core/pipeline/probe.h"
#include "core/pipeline/session.h"
#include "core/render/camera.h"
#include "core/util/error.h"
#include "core/util/threads.h"
#include "core/util/timer.h"

namespace avatar {
namespace {

SessionBenchmarkRow BenchSession(const std::string& config, int repeats, RunContext& ctx) {
  SessionOptions so;
  so.random_weights = true;
  so.config = config;
  Session session(so);
  RunContext quiet;
  const face::AlignedPortrait portrait = ProbePortrait();
  const SourceFit fit = ProbeFit(0);
  SessionBenchmarkRow row;
  row.config = config;
  // First: one reconstruct + one final frame (the peak-memory figure for the paper config).
  Timer first;
  Avatar avatar = session.ReconstructFromAnalysis(portrait, fit, quiet);
  const Frame final_frame = session.Animate(avatar, {{{"jawOpen", 0.3f}}}, ViewPose{10, -5}, RenderMode::kFinal);
  row.first_seconds = first.Seconds();
  row.peak_rss_mb = PeakRssMb();
  row.final_frame_size = final_frame.bgr.cols;
  int step = 0;
  row.full_seconds = MedianSeconds(repeats, ctx, [&] {
    avatar = session.ReconstructFromAnalysis(portrait, fit, quiet);
    session.Animate(avatar, {{{"jawOpen", 0.1f + 0.01f * static_cast<float>(++step)}}}, ViewPose{}, RenderMode::kStandard);
  });
  double yaw = 0.0;
  row.camera_only_seconds = MedianSeconds(repeats, ctx, [&] {
    session.Animate(avatar, {{{"jawOpen", 0.5f}}}, ViewPose{yaw += 7.0, -5}, RenderMode::kStandard);
  });
  row.preview_seconds = MedianSeconds(repeats, ctx, [&] {
    session.Animate(avatar, {{{"jawOpen", 0.5f}}}, ViewPose{yaw += 7.0, -5}, RenderMode::kPreview);
  });
  row.expression_seconds = MedianSeconds(repeats, ctx, [&] {
    session.Animate(avatar, {{{"jawOpen", 0.2f + 0.01f * static_cast<float>(++step)}}}, ViewPose{yaw, -5},
                    RenderMode::kStandard);
  });
  row.final_seconds = MedianSeconds(1, ctx, [&] {
    session.Animate(avatar, {{{"jawOpen", 0.5f}}}, ViewPose{yaw += 7.0, -5}, RenderMode::kFinal);
  });
  return row;
}

std::vector<StageBenchmarkRow> BenchStages(const std::string& config_name, int repeats, RunContext& ctx) {
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
  // Each stage is timed right after its own GEMM-peak measurement: the machine is shared, so
  // every ratio compares two figures taken seconds apart.
  std::vector<StageBenchmarkRow> rows;
  const auto time_stage = [&](const std::string& name, const std::function<void()>& fn) {
    StageBenchmarkRow row;
    row.config = config_name;
    row.stage = name;
    row.gemm_gflops = MeasureGemmGflops(1024, 3);
    row.seconds = MedianSeconds(repeats, ctx, fn);
    rows.push_back(row);
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
  for (auto& row : rows) row.flops = flops.count(row.stage) ? flops[row.stage] : 0.0;
  return rows;
}

RasterizerBenchmark BenchRasterizer(int repeats, RunContext& ctx) {
  torch::manual_seed(1);
  RasterizerBenchmark r;
  const int64_t grid = r.grid, n = grid * grid;
  // Points of a lifted depth map look like a surface: a noisy sphere cap in the unit box.
  const torch::Tensor dir =
      torch::nn::functional::normalize(torch::randn({n, 3}), torch::nn::functional::NormalizeFuncOptions().dim(1));
  const torch::Tensor pts = (dir * 0.35 * (1 + 0.05 * torch::randn({n, 1}))).unsqueeze(0);
  const torch::Tensor feats = torch::randn({1, n, 256});
  const torch::Tensor mask = torch::ones({1, n}, torch::kBool);
  torch::InferenceMode inference;
  r.rasterize_seconds =
      MedianSeconds(std::max(repeats, 5), ctx, [&] { RasterizePointFeatures(pts, mask, feats, grid, 1.0); });
  const torch::Tensor xy = pts[0].narrow(1, 0, 2) * 2.0;
  r.search_seconds = MedianSeconds(repeats, ctx, [&] { NearestPointIndices(xy, grid); });
  Timer brute_timer;
  const auto brute = NearestPointIndicesBruteForce(xy, grid);
  r.brute_force_seconds = brute_timer.Seconds();
  r.identical = brute == NearestPointIndices(xy, grid);
  return r;
}

}  // namespace

void ModelBenchmarkOptions::Validate() const {
  AVATAR_CHECK_OPTION(repeats >= 1 && repeats <= 50) << "--repeats must be 1..50, got " << repeats;
  for (const auto& c : configs) ModelConfig::FromName(c);
}

ModelBenchmarkReport RunModelBenchmark(const ModelBenchmarkOptions& options, int threads, RunContext& ctx,
                                       const ModelBenchmarkListener& listener) {
  options.Validate();
  ModelBenchmarkReport report;
  report.threads = ConfiguredThreads() > 0 ? ConfiguredThreads() : ConfigureThreads(threads);
  report.gemm_before = MeasureGemmGflops();
  if (listener.started) listener.started(report);
  for (const auto& c : options.configs) {
    report.sessions.push_back(BenchSession(c, options.repeats, ctx));
    if (listener.session) listener.session(report.sessions.back());
  }
  report.rasterizer = BenchRasterizer(options.repeats, ctx);
  if (listener.rasterizer) listener.rasterizer(report.rasterizer);
  for (const auto& c : options.configs) {
    const std::vector<StageBenchmarkRow> rows = BenchStages(c, options.repeats, ctx);
    report.stages.insert(report.stages.end(), rows.begin(), rows.end());
    if (listener.stages) listener.stages(rows);
  }
  report.gemm_after = MeasureGemmGflops();
  return report;
}

}  // namespace avatar
