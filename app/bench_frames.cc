// `avatar-studio bench frames`: what one interactive frame of the neural session costs, with the
// inference render skips (RenderSettings: early ray termination, rays missing the tri-plane box,
// empty-space skipping through the occupancy grid) off, each alone, and all on, in ONE run.
//
// On the installed or bundled model and the bundled sample portrait (reconstructed once: face
// analysis, morphable fit, T_c and T_p), it measures per configuration
//   orbit frame       Session::Animate at the model's render size, no SR, at --frames yaw steps
//                     across +-yaw-range about the portrait's camera (the frame sources' camera),
//                     one cached expression: the volume render and the image conversion;
//   expression change Session::Animate with an expression never seen before at a fixed view: the
//                     morphable I_exp render, E_e, T_c + T_p + T_e, the occupancy grid when empty
//                     space is skipped, then the frame.
// The configurations take turns frame by frame (and expression by expression), so the load of a
// shared machine falls on all of them alike; the medians are compared as ratios to the full
// render and to the goals (30 fps = 33.3 ms per frame; 100 ms per expression change). Each
// configuration's frames are also compared with the full render's at the same view (mean abs
// difference of the 8-bit images, in [0,1] units).
// Then the detail path (core/pipeline/detail_source.h) as the studio's frame sources render it: the
// network alone, the detail on the face and on the head, at 256^2 and 512^2 output, over an orbit
// of half the yaw range, with the one-time bake of the head detail. Last, the studio's expression
// sliders with the head detail (a sweep of jawOpen, smile and blinkLeft): the first updated frame
// (the quick frame over the kept network frame) and the refined one (quick + full), against 100
// and 400 ms.

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "app/cli_util.h"
#include "app/cmd_bench.h"
#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/tools/benchmarks.h"
#include "core/pipeline/session.h"
#include "core/pipeline/studio_backend.h"
#include "core/util/error.h"
#include "core/util/threads.h"
#include "core/util/timer.h"

namespace avatar::app {

namespace {

constexpr double kFrameGoalMs = 1000.0 / 30.0;  // 30 fps
constexpr double kExpressionGoalMs = 100.0;

struct BenchFramesOptions {
  // Model checkpoint ("" = the installed or bundled model).
  std::string checkpoint;
  // Fusion net weights of the learned path's row ("" = the bundled net, FusionWeightsOf).
  std::string fusion;
  // Portrait photo ("" = the bundled sample portrait, samples/grace_hopper.jpg in the data folder).
  std::string portrait;
  // Orbit frames per configuration and pass.
  int frames = 24;
  // Orbit passes (the median is taken over every frame of every pass).
  int repeats = 1;
  // Expression changes per configuration.
  int expressions = 6;
  // The orbit's yaw range: frames from -yaw_range to +yaw_range degrees about the portrait's camera.
  double yaw_range = 60.0;
  // Also time each skip alone (else only all off and all on).
  bool each_skip = true;
  // Threads, data folder, verbosity.
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("checkpoint", checkpoint, "Model checkpoint (default: the installed or bundled model)");
    v("fusion", fusion, "Fusion net weights of the learned path's row (default: the bundled net)");
    v("portrait", portrait, "Portrait photo (default: the bundled sample portrait)");
    v("frames", frames, "Orbit frames per configuration and pass");
    v("repeats", repeats, "Orbit passes (median over all frames)");
    v("expressions", expressions, "Expression changes per configuration");
    v("yaw_range", yaw_range, "Orbit yaw range in degrees (-range..+range about the portrait's camera)");
    v("each_skip", each_skip, "Also time each skip alone (--no-each-skip: only all off and all on)");
    common.Visit(v);
  }
  void Validate() const {
    AVATAR_CHECK_OPTION(frames >= 2 && frames <= 1000) << "--frames must be 2..1000, got " << frames;
    AVATAR_CHECK_OPTION(repeats >= 1 && repeats <= 100) << "--repeats must be 1..100, got " << repeats;
    AVATAR_CHECK_OPTION(expressions >= 1 && expressions <= 200) << "--expressions must be 1..200, got " << expressions;
    AVATAR_CHECK_OPTION(std::isfinite(yaw_range) && yaw_range >= 0.0 && yaw_range <= 180.0)
        << "--yaw-range must be 0..180 degrees, got " << yaw_range;
    common.Validate();
  }
};

struct FrameConfig {
  std::string name;
  RenderSettings settings;
  std::vector<double> frame_ms, expression_ms;
  std::vector<double> change;  // mean abs difference to the full render per orbit frame, [0,1]
};

RenderSettings WithSkips(bool early_termination, bool missed_rays, bool empty_space) {
  RenderSettings s;  // the model's render size and samples, no SR, opacity and depth as the frame sources ask
  s.early_termination = early_termination;
  s.skip_missed_rays = missed_rays;
  s.skip_empty_space = empty_space;
  return s;
}

double MeanAbsDifference(const cv::Mat& a, const cv::Mat& b) {
  AVATAR_CHECK(a.size() == b.size() && a.type() == b.type()) << "frames of different sizes";
  cv::Mat diff;
  cv::absdiff(a, b, diff);
  const cv::Scalar mean = cv::mean(diff);
  return (mean[0] + mean[1] + mean[2]) / 3.0 / 255.0;
}

std::string Ratio(double value) { return Fixed(value, 2) + "x"; }

int RunBenchFramesImpl(const BenchFramesOptions& options, RunContext& ctx) {
  options.Validate();
  const int threads = ConfiguredThreads() > 0 ? ConfiguredThreads() : ConfigureThreads(options.common.threads);
  const double gemm = MeasureGemmGflops();

  SessionOptions so;
  so.checkpoint = options.checkpoint;
  so.data_dir = options.common.data_dir;
  so.render_skips = true;  // the configurations choose their skips per frame
  so.expression_cache = 64;
  Timer load_timer;
  const Session session(so);
  const double load_s = load_timer.Seconds();
  const ModelInfo info = session.Info();
  const std::filesystem::path portrait_path =
      options.portrait.empty()
          ? DataPaths::Resolve(options.common.data_dir).Require(DataPaths::kDefaultPortrait, "the sample portrait")
          : std::filesystem::path(options.portrait);
  const cv::Mat photo = LoadImageBgr(portrait_path);
  Timer reconstruct_timer;
  RunContext quiet;
  const Avatar avatar = session.Reconstruct(photo, quiet);
  const double reconstruct_s = reconstruct_timer.Seconds();

  std::vector<FrameConfig> configs;
  configs.push_back({"full render (skips off)", WithSkips(false, false, false), {}, {}, {}});
  if (options.each_skip) {
    configs.push_back({"early ray termination", WithSkips(true, false, false), {}, {}, {}});
    configs.push_back({"rays missing the box", WithSkips(false, true, false), {}, {}, {}});
    configs.push_back({"empty space (occupancy grid)", WithSkips(false, false, true), {}, {}, {}});
  }
  configs.push_back({"all skips (session default)", WithSkips(true, true, true), {}, {}, {}});

  const auto camera_at = [&](double yaw) {
    ViewPose pose;
    pose.yaw = yaw;
    return render::CameraForView(pose, avatar.SourceCamera());
  };
  // Warm-up: the neutral expression's planes (and, for the skipping configurations, its grid).
  const Expression neutral;
  for (const auto& c : configs) session.Animate(avatar, neutral, camera_at(0.0), c.settings);

  std::cout << "Frame benchmark: " << DescribeModel(info) << "\n"
            << "Portrait " << portrait_path.filename().string() << "; model load " << Fixed(load_s, 2)
            << " s, reconstruct (face analysis + fit + T_c, T_p) " << Fixed(reconstruct_s, 2) << " s. " << threads
            << " threads; GEMM peak (fp32 1024^3, best of 5) " << Fixed(gemm, 1) << " GFLOP/s.\n"
            << "Frames: " << info.render_size << "^2 render (the model's), no SR; orbit of " << options.frames
            << " yaw steps over +-" << Fixed(options.yaw_range, 0) << " deg x " << options.repeats
            << " pass(es); " << options.expressions
            << " expression changes (new I_exp + E_e + planes + frame) per configuration.\n\n"
            << std::flush;

  // Orbit: the configurations take turns at each view.
  for (int pass = 0; pass < options.repeats; ++pass) {
    for (int i = 0; i < options.frames; ++i) {
      ctx.ThrowIfCancelled();
      const double yaw = -options.yaw_range + 2.0 * options.yaw_range * i / (options.frames - 1);
      const auto camera = camera_at(yaw);
      cv::Mat full;
      for (auto& c : configs) {
        Timer timer;
        const Frame frame = session.Animate(avatar, neutral, camera, c.settings);
        c.frame_ms.push_back(timer.Milliseconds());
        if (full.empty()) full = frame.bgr;  // configs[0] is the full render
        if (pass == 0) c.change.push_back(MeanAbsDifference(full, frame.bgr));
      }
    }
  }
  // Expression changes: a new expression (never cached) per configuration and step, on the
  // portrait's jawOpen control (else its first control).
  const std::vector<std::string> controls = avatar.ControlNames();
  AVATAR_CHECK_INPUT(!controls.empty()) << "the portrait's expression source has no controls";
  const std::string control =
      std::find(controls.begin(), controls.end(), "jawOpen") != controls.end() ? "jawOpen" : controls.front();
  const int changes = options.expressions * static_cast<int>(configs.size());
  int unique = 0;
  for (int e = 0; e < options.expressions; ++e) {
    for (auto& c : configs) {
      ctx.ThrowIfCancelled();
      Expression expression;
      expression.controls[control] = 0.05f + 0.9f * static_cast<float>(++unique) / static_cast<float>(changes);
      Timer timer;
      session.Animate(avatar, expression, camera_at(10.0), c.settings);
      c.expression_ms.push_back(timer.Milliseconds());
    }
  }

  const double full_frame = Median(configs[0].frame_ms), full_expression = Median(configs[0].expression_ms);
  std::cout << "| configuration | orbit frame (median ms) | fps | vs full | vs 30 fps goal (33.3 ms) | expression change "
               "(median ms) | vs full | vs 100 ms goal | mean abs change vs full |\n"
            << "|---|---|---|---|---|---|---|---|---|\n";
  for (const auto& c : configs) {
    const double frame = Median(c.frame_ms), expression = Median(c.expression_ms);
    double change = 0.0;
    for (double d : c.change) change += d;
    change /= static_cast<double>(std::max<size_t>(1, c.change.size()));
    char change_text[32];
    std::snprintf(change_text, sizeof(change_text), "%.1e", change);
    std::cout << "| " << c.name << " | " << Fixed(frame, 1) << " | " << Fixed(1000.0 / frame, 1) << " | "
              << Ratio(frame / full_frame) << " | " << Ratio(frame / kFrameGoalMs) << " | " << Fixed(expression, 1)
              << " | " << Ratio(expression / full_expression) << " | " << Ratio(expression / kExpressionGoalMs)
              << " | " << change_text << " |\n";
  }
  std::cout << "\n'vs full' = median time with the configuration / with every skip off (below 1 = faster); "
               "'vs goal' = median time / goal (at most 1 meets it).\n"
            << std::flush;

  // The detail path: the studio's frame sources of the same portrait (one analysis), the
  // network alone and under the photo's detail, taking turns at each view and output size.
  BackendOptions backend;
  backend.checkpoint = options.checkpoint;
  backend.data_dir = options.common.data_dir;
  backend.fusion = options.fusion;
  const PortraitPaths paths = CreatePortraitPaths(photo, backend, quiet);
  std::vector<std::pair<std::string, const FrameSource*>> sources = {
      {"network alone (--detail off)", paths.network.get()},
      {"detail on the face (--detail face)", paths.face.get()},
      {"detail on the head, geometric composite (--detail geometric)", paths.detail.get()}};
  if (paths.learned) sources.push_back({"detail on the head + fusion net (--detail head, default)", paths.learned.get()});
  std::cout << "\nDetail path (frame sources as the studio and animate use them; the bake = the head detail's "
               "source-view depth and face depth, once per avatar: "
            << Fixed(paths.bake_seconds, 3) << " s):\n\n"
            << "| output | path | frame (median ms) | vs network alone | detail's share of the frame |\n"
            << "|---|---|---|---|---|\n";
  for (const int size : {256, 512}) {
    std::vector<std::vector<double>> ms(sources.size());
    for (int i = 0; i < options.frames; ++i) {
      ctx.ThrowIfCancelled();
      FrameRequest request;
      request.view = paths.network->SourcePose();
      request.view.yaw += -options.yaw_range / 2.0 + options.yaw_range * i / (options.frames - 1);
      request.width = request.height = size;
      for (size_t k = 0; k < sources.size(); ++k) {
        Timer timer;
        sources[k].second->Render(request, quiet);
        ms[k].push_back(timer.Milliseconds());
      }
    }
    const double base = Median(ms[0]);
    for (size_t k = 0; k < sources.size(); ++k) {
      const double m = Median(ms[k]);
      std::cout << "| " << size << "^2 | " << sources[k].first << " | " << Fixed(m, 1) << " | " << Ratio(m / base)
                << " | " << (k == 0 ? std::string("-") : Fixed(100.0 * (m - base) / m, 0) + "%") << " |\n";
    }
  }
  std::cout << "\nOrbit of the detail rows: " << options.frames << " views over +-" << Fixed(options.yaw_range / 2.0, 0)
            << " deg about the portrait's pose.\n";

  // An expression slider in the studio (the preview worker's schedule): at an unchanged view a new
  // expression is first composed over the last network frame (RenderQuick: no network call),
  // then the full frame follows. Each step a new jawOpen value (never cached).
  constexpr double kFirstGoalMs = 100.0, kRefinedGoalMs = 400.0;
  // The studio's default: the head detail finished by the fusion net when one is installed.
  const auto& studio = paths.learned ? paths.learned : paths.detail;
  std::cout << "\nExpression changes in the studio with the head detail" << (paths.learned ? " + fusion net" : "")
            << " (first frame = the quick frame; refined = quick + full frame, as the viewport shows them; "
            << options.expressions << " new expressions per size, sweeping jawOpen, smile and blinkLeft in turn):\n\n"
            << "| output | first updated frame (median ms) | vs 100 ms goal | refined frame (median ms) | vs 400 ms goal "
               "| full frame alone (median ms) |\n"
            << "|---|---|---|---|---|---|\n";
  // A scripted sweep of three controls (jawOpen, smile, blinkLeft when the portrait has them).
  std::vector<std::string> sliders;
  for (const char* name : {"jawOpen", "smile", "blinkLeft"}) {
    if (std::find(controls.begin(), controls.end(), name) != controls.end()) sliders.push_back(name);
  }
  if (sliders.empty()) sliders.push_back(control);
  int step = 0;
  for (const int size : {256, 512}) {
    FrameRequest request;
    request.view = paths.network->SourcePose();
    request.view.yaw += 10.0;
    request.width = request.height = size;
    studio->Render(request, quiet);  // the view's network frame, kept
    std::vector<double> first, refined, full;
    for (int e = 0; e < options.expressions; ++e) {
      ctx.ThrowIfCancelled();
      ++step;
      request.expression.controls[sliders[static_cast<size_t>(step) % sliders.size()]] =
          0.05f + 0.9f * static_cast<float>(step) / (2.0f * options.expressions);
      Timer timer;
      const std::optional<RenderedFrame> quick = studio->RenderQuick(request, quiet);
      AVATAR_CHECK_INPUT(quick.has_value()) << "the detail path kept no frame of this view";
      first.push_back(timer.Milliseconds());
      Timer full_timer;
      studio->Render(request, quiet);
      full.push_back(full_timer.Milliseconds());
      refined.push_back(timer.Milliseconds());
    }
    std::cout << "| " << size << "^2 | " << Fixed(Median(first), 1) << " | " << Ratio(Median(first) / kFirstGoalMs)
              << " | " << Fixed(Median(refined), 1) << " | " << Ratio(Median(refined) / kRefinedGoalMs) << " | "
              << Fixed(Median(full), 1) << " |\n";
  }
  std::cout << "\nPeak RSS " << Fixed(PeakRssMb(), 0) << " MB." << std::endl;
  return kExitOk;
}

int RunBenchFrames(const std::vector<std::string>& args) {
  return RunBenchSubject<BenchFramesOptions>(
      args, "frames",
      "Times the neural session's interactive frames on the installed or bundled model and the sample\n"
      "portrait: an orbit of cached-expression frames and expression changes (new expression -> new\n"
      "frame), with the inference render skips off, each alone and all on, taking turns in one run.\n"
      "Prints medians, ratios to the full render and to the goals (30 fps, 100 ms per expression\n"
      "change), and each configuration's mean abs image change against the full render.",
      RunBenchFramesImpl);
}

}  // namespace

AVATAR_REGISTER_BENCH_SUBJECT("frames", "Interactive frame and expression-change time, render skips off / on",
                              RunBenchFrames);

}  // namespace avatar::app
