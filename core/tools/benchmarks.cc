#include "core/tools/benchmarks.h"

#include <sys/resource.h>

#include <algorithm>
#include <cstdio>
#include <map>
#include <sstream>

#include <torch/torch.h>

#include "core/face/face_analyzer.h"
#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/io/video_io.h"
#include "core/model/triplane_decoder.h"
#include "core/render/camera.h"
#include "core/morphable/morphable.h"
#include "core/render/renderer.h"
#include "core/util/error.h"
#include "core/util/threads.h"
#include "core/util/measure.h"
#include "core/util/timer.h"

namespace avatar {
namespace {

// One render benchmark configuration.
struct RenderCase {
  const char* name;
  int resolution;
  int num_coarse;
  int num_importance;
  int plane_size;
};

const std::vector<RenderCase>& RenderCases() {
  static const std::vector<RenderCase> cases = {
      {"paper", 128, 48, 48, 256},  // the paper's render: 128^2 rays, 48 + 48 samples, 3x32x256^2 planes
      {"medium", 64, 48, 48, 256},
      {"small", 64, 24, 24, 128},
      {"tiny", 32, 12, 12, 64},
  };
  return cases;
}

}  // namespace

std::vector<std::string> RenderBenchmarkCases() {
  std::vector<std::string> names;
  for (const auto& c : RenderCases()) names.push_back(c.name);
  return names;
}

void RenderBenchmarkOptions::Validate() const {
  AVATAR_CHECK_OPTION(repeats >= 1 && repeats <= 100) << "--repeats must be 1..100, got " << repeats;
  AVATAR_CHECK_OPTION(batch >= 1 && batch <= 64) << "--batch must be 1..64, got " << batch;
  AVATAR_CHECK_OPTION(chunk_rays >= 1) << "--chunk-rays must be >= 1, got " << chunk_rays;
  for (const auto& name : SplitList(cases)) {
    bool known = name == "all";
    for (const auto& c : RenderCases()) known = known || name == c.name;
    AVATAR_CHECK_OPTION(known) << "unknown case '" << name << "' (paper, medium, small, tiny, all)";
  }
}

RenderBenchmarkReport RunRenderBenchmark(const RenderBenchmarkOptions& options, int threads_flag, RunContext& ctx,
                                         const std::function<void(const RenderBenchmarkReport&)>& on_start,
                                         const std::function<void(const RenderBenchmarkRow&)>& on_row) {
  options.Validate();
  const auto wanted = SplitList(options.cases);
  const bool all = std::find(wanted.begin(), wanted.end(), "all") != wanted.end();
  RenderBenchmarkReport report;
  report.threads = ConfiguredThreads() > 0 ? ConfiguredThreads() : ConfigureThreads(threads_flag);
  torch::InferenceMode inference;
  torch::manual_seed(0);

  report.gemm_before = MeasureGemmGflops();
  if (on_start) on_start(report);
  for (const auto& rc : RenderCases()) {
    if (!all && std::find(wanted.begin(), wanted.end(), rc.name) == wanted.end()) continue;
    ctx.ThrowIfCancelled();
    render::RenderOptions ro;
    ro.resolution = rc.resolution;
    ro.num_coarse = rc.num_coarse;
    ro.num_importance = rc.num_importance;
    ro.chunk_rays = options.chunk_rays;
    const int64_t b = options.batch;
    TriplaneDecoder decoder;
    const torch::Tensor planes = torch::randn({b, 3, kDecoderInputChannels, rc.plane_size, rc.plane_size});
    const render::Cameras cameras = render::FrontalCameras(b);
    const render::PointDecoder decode = [&](const torch::Tensor& f) { return decoder->forward(f); };
    render::RenderOutput warm = render::RenderTriplanes(planes, decode, cameras, ro);
    AVATAR_CHECK(torch::isfinite(warm.features).all().item<bool>()) << "benchmark render produced non-finite values";
    std::vector<double> seconds;
    double sample_ns = 0, decode_ns = 0, total_ns = 0, points = 0;
    for (int i = 0; i < options.repeats; ++i) {
      ctx.ThrowIfCancelled();
      render::RenderProfile profile;
      Timer timer;
      render::RenderTriplanes(planes, decode, cameras, ro, c10::nullopt, &profile);
      seconds.push_back(timer.Seconds());
      sample_ns += static_cast<double>(profile.sample_ns.load());
      decode_ns += static_cast<double>(profile.decode_ns.load());
      total_ns += static_cast<double>(profile.total_ns.load());
      points += static_cast<double>(profile.points.load());
    }
    std::sort(seconds.begin(), seconds.end());
    RenderBenchmarkRow row;
    row.name = rc.name;
    row.batch = b;
    row.resolution = rc.resolution;
    row.num_coarse = rc.num_coarse;
    row.num_importance = rc.num_importance;
    row.plane_size = rc.plane_size;
    row.median_seconds = seconds[seconds.size() / 2];
    const double rays = static_cast<double>(b) * rc.resolution * rc.resolution;
    const double samples = rays * (rc.num_coarse + rc.num_importance);
    row.rays_per_second = rays / row.median_seconds;
    row.samples_per_second = samples / row.median_seconds;
    // Thread-summed stage times; their wall share is the same fraction of the render.
    const double decode_wall = decode_ns * 1e-9 / report.threads / options.repeats;
    const double flops = decoder->FlopsPerPoint() * points / options.repeats;
    row.decoder_gflops = decode_wall > 0 ? flops / decode_wall / 1e9 : 0.0;
    row.sample_share = sample_ns / total_ns;
    row.decoder_share = decode_ns / total_ns;
    row.other_share = (total_ns - sample_ns - decode_ns) / total_ns;
    report.rows.push_back(row);
    if (on_row) on_row(row);
  }
  report.gemm_after = MeasureGemmGflops();
  return report;
}

void FaceBenchmarkOptions::Validate() const {
  AVATAR_CHECK_OPTION(repeats >= 1 && repeats <= 100) << "--repeats must be 1..100";
  AVATAR_CHECK_OPTION(frames >= 1) << "--frames must be >= 1";
}

FaceBenchmarkReport RunFaceBenchmark(const FaceBenchmarkOptions& o, RunContext& ctx) {
  o.Validate();
  const DataPaths paths = DataPaths::Resolve(o.data_dir);
  FaceBenchmarkReport out;
  out.gemm_gflops = MeasureGemmGflops();
  face::FaceAnalyzerOptions fo;
  fo.data_dir = o.data_dir;
  Timer load;
  const face::FaceAnalyzer analyzer(fo);
  out.model_load_ms = load.Milliseconds();
  for (const char* name : {"grace_hopper.jpg", "sample1.jpg"}) {
    const cv::Mat image = LoadImageBgr(paths.Require(std::string("samples/") + name, "benchmark photo"));
    std::map<std::string, std::vector<double>> times;
    std::vector<std::string> order;
    for (int r = 0; r <= o.repeats; ++r) {
      face::PortraitReport report;
      analyzer.AnalyzePortrait(image, ctx, &report);
      if (r == 0) {
        for (const auto& s : report.timings) order.push_back(s.stage);
        continue;  // warm-up
      }
      double total = 0;
      for (const auto& s : report.timings) {
        times[s.stage].push_back(s.ms);
        total += s.ms;
      }
      times["total"].push_back(total);
    }
    order.push_back("total");
    for (const auto& stage : order) {
      auto v = times[stage];
      std::sort(v.begin(), v.end());
      out.stages.push_back({name, stage, v[v.size() / 2]});
    }
  }
  VideoReader reader(paths.Require("samples/franck.mp4", "benchmark clip"));
  face::FaceTracker tracker(analyzer);
  cv::Mat frame;
  int n = 0;
  Timer t;
  while (n < o.frames && reader.Read(frame)) {
    ctx.ThrowIfCancelled();
    tracker.Track(frame, n / 25.0);
    ++n;
  }
  out.tracked_frames = n;
  out.track_ms_per_frame = t.Milliseconds() / std::max(1, n);
  return out;
}

namespace {

// Median milliseconds of `fn` over `repeats` runs after a warm-up (the upper middle value).

}  // namespace

void MorphableBenchmarkOptions::Validate() const {
  AVATAR_CHECK_OPTION(repeats >= 1 && repeats <= 100) << "--repeats must be in 1..100";
  AVATAR_CHECK_OPTION(frames >= 2 && frames <= 5000) << "--frames must be in 2..5000";
}

MorphableBenchmarkReport RunMorphableBenchmark(const MorphableBenchmarkOptions& o, RunContext& ctx) {
  o.Validate();
  const DataPaths paths = DataPaths::Resolve(o.data_dir);
  const morphable::MorphableModel& m = morphable::LoadDefaultModel(paths);
  MorphableBenchmarkReport out;
  out.identity_components = m.num_identity();
  out.expression_components = m.num_expression();
  out.gemm_gflops = MeasureGemmGflops();
  out.gemm_ms = 2.0 * 1024 * 1024 * 1024 / (out.gemm_gflops * 1e9) * 1e3;
  // Synthetic landmarks: a random-ish face seen from a turned camera, facemesh depth convention.
  render::ViewPose pose;  // The camera 20 degrees to the side and 5 above.
  pose.yaw = 20;
  pose.pitch = -5;
  const morphable::CameraLabel cam = morphable::LabelFromTensor(
      render::LabelsFromCameras({render::OrbitCam2World(pose).unsqueeze(0), render::DefaultIntrinsics().unsqueeze(0)}));
  const cv::Size crop(512, 512);
  morphable::Beta beta = m.ExpressionFromControls({{"jawOpen", 0.5f}, {"smile", 0.3f}});
  const auto world = m.Vertices({}, beta);
  const morphable::PinholeCamera pc = morphable::PinholeCamera::FromLabel(cam);
  face::Landmarks lm;
  double zmean = 0;
  std::vector<cv::Vec3d> c;
  for (const auto& p : world) {
    c.push_back(pc.ToCamera(cv::Vec3d(p.x, p.y, p.z)));
    zmean += c.back()[2] / world.size();
  }
  for (const auto& q : c) {
    const cv::Point2d px = pc.ToPixel(q, crop);
    lm.points.emplace_back(px.x, px.y, render::kFocal * crop.width * (q[2] - zmean) / zmean);
  }
  ctx.ThrowIfCancelled();
  morphable::FitResult fit;
  out.fit_ms = 1000.0 * MedianSeconds(o.repeats, ctx, [&] { fit = morphable::Fit(m, lm, crop); });
  cv::Mat source(crop, CV_8UC3, cv::Scalar(90, 120, 160));
  morphable::Texture tex;
  out.texture_ms = 1000.0 * MedianSeconds(o.repeats, ctx, [&] { tex = morphable::SampleTexture(m, fit, source); });
  morphable::RenderOptions ss1, ss2;
  ss2.supersample = 2;
  ctx.ThrowIfCancelled();
  out.render_ms = 1000.0 * MedianSeconds(o.repeats, ctx, [&] { morphable::RenderNeutral(m, fit, tex, crop, ss1); });
  out.render_supersampled_ms = 1000.0 * MedianSeconds(o.repeats, ctx, [&] { morphable::RenderNeutral(m, fit, tex, crop, ss2); });
  out.render_256_ms = 1000.0 * MedianSeconds(o.repeats, ctx, [&] {
    morphable::RenderExpressionImage(m, fit, tex, beta, {256, 256}, ss1);
  });
  std::vector<face::Landmarks> frames(o.frames, lm);
  const double seq_ms = 1000.0 * MedianSeconds(1, ctx, [&] { morphable::FitSequence(m, frames, crop, morphable::FitOptions{}, ctx); });
  out.sequence_ms_per_frame = seq_ms / o.frames;
  return out;
}

}  // namespace avatar
