#include "core/pipeline/animate.h"

#include <cmath>

#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/io/video_io.h"
#include "core/util/error.h"

namespace avatar {
namespace {

constexpr double kPi = 3.14159265358979323846;

}  // namespace

void AnimationView::Validate() const {
  AVATAR_CHECK_OPTION(mode == "driver" || mode == "source" || mode == "orbit")
      << "--view must be driver, source or orbit, got '" << mode << "'";
  AVATAR_CHECK_OPTION(std::isfinite(orbit_degrees) && orbit_degrees >= 0.0 && orbit_degrees <= 90.0)
      << "--orbit-degrees must be within 0..90, got " << orbit_degrees;
  AVATAR_CHECK_OPTION(std::isfinite(zoom) && zoom >= 0.25 && zoom <= 4.0)
      << "--zoom must be within 0.25..4, got " << zoom;
}

FrameRequest PlanFrame(const FrameSource& source, const AnimationPlan& plan, const DrivingSample* sample,
                       bool driver_is_video, int64_t index, int64_t total) {
  const ViewPose base = source.SourcePose();
  // The user's view offset of this frame: the plan's zoom, plus the turntable's yaw.
  ViewPose user;
  user.zoom = plan.view.zoom;
  if (plan.view.mode == "driver" && sample != nullptr && !driver_is_video) {
    // Keyframes give the camera directly (its zoom times the plan's).
    FrameRequest r = ComposeFrame(ViewPose{}, sample->pose, plan.base_expression, sample, false, plan.width,
                                  plan.height);
    r.view.zoom = sample->pose.zoom * plan.view.zoom;
    return r;
  }
  if (plan.view.mode == "orbit") {
    const double phase = total > 1 ? 2.0 * kPi * static_cast<double>(index) / static_cast<double>(total) : 0.0;
    user.yaw = plan.view.orbit_degrees * std::sin(phase);
  }
  // A video's pose is measured on the driver's head: in relative mode it is an offset from the
  // neutral frame, applied on top of the portrait's own pose (the same composition as the
  // studio's preview).
  const bool follow = plan.view.mode == "driver" && driver_is_video;
  return ComposeFrame(base, user, plan.base_expression, sample, follow, plan.width, plan.height);
}

ExportStats ExportAnimation(const FrameSource& source, Driver* driver, const AnimationPlan& plan, ExportOptions output,
                            RunContext& ctx) {
  plan.view.Validate();
  ValidateFrameSize(plan.width, plan.height);
  AVATAR_CHECK_OPTION(plan.max_frames >= 0) << "--max-frames must be >= 0";
  const bool video = driver != nullptr && dynamic_cast<VideoDriver*>(driver) != nullptr;
  output.fps = video ? driver->Fps() : (driver != nullptr ? driver->Fps() : plan.fps);
  AVATAR_CHECK_OPTION(std::isfinite(output.fps) && output.fps > 0.0) << "--fps must be > 0, got " << output.fps;
  if (driver == nullptr) {
    AVATAR_CHECK_OPTION(std::isfinite(plan.seconds) && plan.seconds > 0.0 && plan.seconds <= 3600.0)
        << "--seconds must be within (0, 3600], got " << plan.seconds;
  }
  output.audio_from = (plan.keep_audio && driver != nullptr) ? driver->AudioSource() : std::string();
  if (output.ResolvedFormat() != "mp4") output.audio_from.clear();

  const int64_t total =
      driver != nullptr ? driver->FrameCount() : std::max<int64_t>(1, std::llround(plan.seconds * output.fps));
  const int64_t expected = plan.max_frames > 0 ? std::min(plan.max_frames, total) : total;
  DrivingSample sample;
  // Progress: the exporter reports frame i of `expected`; sources only check ctx for cancel.
  auto produce = [&](int64_t i, ExportFrame& frame) {
    if (driver != nullptr) {
      if (!driver->Next(sample, ctx)) return false;
    } else if (i >= total) {
      return false;
    }
    const FrameRequest request =
        PlanFrame(source, plan, driver != nullptr ? &sample : nullptr, video, i, std::max<int64_t>(total, 1));
    RenderedFrame rendered = source.Render(request, ctx);
    frame.bgr = std::move(rendered.bgr);
    frame.alpha = std::move(rendered.alpha);
    return true;
  };
  return ExportFrames(produce, expected, plan.width, plan.height, output, ctx, plan.max_frames);
}

void AnimateOptions::Validate() const {
  AVATAR_CHECK_OPTION(!source.empty()) << "missing PORTRAIT: give the source photo (first argument or --source)";
  AVATAR_CHECK_OPTION(!output.empty()) << "--output is required (a .mp4 file or a folder for PNG frames)";
  AnimationView{view, orbit_degrees, zoom}.Validate();
  ValidateFrameSize(width, height);
  AVATAR_CHECK_OPTION(std::isfinite(fps) && fps > 0.0 && fps <= 240.0) << "--fps must be within (0,240], got " << fps;
  AVATAR_CHECK_OPTION(std::isfinite(seconds) && seconds > 0.0 && seconds <= 3600.0)
      << "--seconds must be within (0,3600], got " << seconds;
  AVATAR_CHECK_OPTION(max_frames >= 0) << "--max-frames must be >= 0, got " << max_frames;
  driving.Validate();
  backend.Validate();
  ExportOptions e;
  e.output = output;
  e.format = format;
  e.Validate();
  // Checked here, before the portrait's analysis, rather than when the encoder opens.
  AVATAR_CHECK_OPTION(e.ResolvedFormat() != "mp4" || (width % 2 == 0 && height % 2 == 0))
      << "MP4 (H.264) export needs an even --width and --height, got " << width << "x" << height
      << "; use an even size or export PNG frames (-o FOLDER)";
}

AnimationPlan AnimateOptions::Plan() const {
  AnimationPlan plan;
  plan.view = AnimationView{view, orbit_degrees, zoom};
  plan.width = width;
  plan.height = height;
  plan.fps = fps;
  plan.seconds = seconds;
  plan.max_frames = max_frames;
  plan.keep_audio = audio;
  return plan;
}

AnimateResult RunAnimation(const AnimateOptions& options, RunContext& ctx) {
  options.Validate();
  std::unique_ptr<Driver> driver;
  if (!options.driver.empty()) {
    // A bad driver is refused before the portrait's (slow) analysis: keyframes (and a file that
    // is neither keyframes nor a video) are opened now; a video is opened once to check it.
    if (IsVideoPath(options.driver)) {
      VideoReader check(options.driver);
    } else {
      driver = OpenDriver(options.driver, nullptr, options.driving, ctx);
    }
  }
  ctx.Report("load portrait", 0.0, options.source);
  const cv::Mat portrait = LoadImageBgr(options.source);
  std::shared_ptr<const FrameSource> source;
  {
    RunContext::ProgressRange range(ctx, 0.0, 0.1);
    try {
      source = CreateFrameSource(portrait, options.backend, ctx);
    } catch (const InvalidInput& e) {
      throw InvalidInput("portrait '" + options.source + "': " + e.what());
    }
  }
  if (!options.driver.empty() && driver == nullptr) {
    RunContext::ProgressRange range(ctx, 0.1, 0.15);
    driver = OpenDriver(options.driver, DrivingAnalyzers(options.backend), options.driving, ctx);
  }
  if (driver != nullptr) driver->CheckControls(source->ExpressionControls());
  ExportOptions out;
  out.output = options.output;
  out.format = options.format;
  AnimateResult result;
  result.source_label = source->Label();
  result.driver_measured = driver != nullptr && driver->Measured();
  if (const auto* video = dynamic_cast<const VideoDriver*>(driver.get())) {
    result.driver_note = video->Video().NeutralNote();
    result.neutral_frame = video->Video().NeutralFrame();
  }
  {
    RunContext::ProgressRange range(ctx, 0.15, 1.0);
    result.stats = ExportAnimation(*source, driver.get(), options.Plan(), out, ctx);
  }
  result.fps = driver != nullptr ? driver->Fps() : options.fps;
  return result;
}

}  // namespace avatar
