#include <cmath>
#include <iostream>

#include <opencv2/imgproc.hpp>

#include "app/cli_util.h"
#include "app/cmd_reconstruct.h"
#include "core/io/image_io.h"
#include "core/pipeline/studio_backend.h"
#include "core/util/error.h"
#include "core/util/timer.h"

namespace avatar::app {

BackendOptions RenderCommandOptions::Backend() const {
  BackendOptions b;
  b.detail = detail;
  b.fusion = fusion;
  b.data_dir = common.data_dir;
  b.random_weights = session.random_weights;
  b.checkpoint = session.checkpoint;
  return b;
}

void RenderCommandOptions::Validate() const {
  AVATAR_CHECK_OPTION(!input.empty()) << "missing FILE.avatar: give the avatar to render";
  AVATAR_CHECK_OPTION(!output.empty()) << "--output must not be empty";
  AVATAR_CHECK_OPTION(std::isfinite(yaw) && std::isfinite(roll) && std::isfinite(pitch) && std::abs(pitch) < 90.0)
      << "--yaw, --pitch and --roll must be finite, --pitch within (-90, 90) degrees, got pitch " << pitch;
  RenderModeFromName(mode);
  ParseExpressionFlags(expr);
  ValidateFrameSize(size, size);
  Backend().Validate();
  session.Validate();
  common.Validate();
}

int RunRenderImpl(const RenderCommandOptions& options, RunContext& ctx) {
  options.Validate();
  SessionOptions so = options.session;
  so.data_dir = options.common.data_dir;
  const AvatarFileInfo file = ReadAvatarFileInfo(options.input);
  if (so.random_weights && so.checkpoint.empty()) {
    // The avatar names its random weights (RandomModelId): rebuild exactly those.
    ParseRandomModelId(file.model_id, &so.config, &so.seed);
  }
  Timer timer;
  const auto session = std::make_shared<const Session>(so);
  if (so.random_weights && so.checkpoint.empty()) {
    std::cerr << "warning: rendering with the UNTRAINED network's random weights (" << session->Info().model_id
              << "); the frame is not a result.\n";
  }
  const Avatar avatar = session->LoadAvatar(options.input);
  // The flags name the camera (pitch > 0: the camera above, looking down); the pose names the
  // head, which tilts down and rolls the other way in that picture.
  ViewPose view;
  view.yaw = options.yaw;
  view.pitch = -options.pitch;
  view.roll = -options.roll;
  const RenderMode mode = RenderModeFromName(options.mode);
  const RenderSettings settings = RenderSettingsFor(mode, session->Info().render_size);
  const std::shared_ptr<const FrameSource> source = SavedAvatarSource(session, avatar, options.Backend(), &settings);
  for (const std::string& w : source->Warnings()) std::cerr << "warning: " << w << "\n";
  cv::Mat bgr, alpha, depth;
  bool upsampled = false;
  if (source->Wrapped() != nullptr) {
    // The photo's detail path: one frame at the requested size.
    FrameRequest request;
    request.view = view;
    request.expression = ParseExpressionFlags(options.expr);
    request.width = request.height = options.size;
    const RenderedFrame frame = source->Render(request, ctx);
    bgr = frame.bgr;
    alpha = frame.alpha;
    if (!frame.depth.empty()) cv::min(frame.depth, 3.3, depth);
  } else {
    const Frame frame = session->Animate(avatar, ParseExpressionFlags(options.expr), view, mode, &ctx);
    bgr = frame.bgr;
    frame.opacity.convertTo(alpha, CV_8U, 255.0);
    depth = frame.depth;
    upsampled = frame.upsampled;
  }
  cv::Mat out = bgr;
  if (options.alpha) {
    cv::Mat channels[4];
    cv::split(bgr, channels);
    channels[3] = alpha;
    cv::merge(channels, 4, out);
  }
  SaveImage(options.output, out);
  std::cout << "Rendered '" << options.input << "' (" << bgr.cols << "x" << bgr.rows << ", mode " << options.mode
            << (upsampled ? ", render upsampled" : "") << ") with the " << DescribeModel(session->Info()) << " ("
            << source->Label() << ") to '" << options.output << "'";
  if (options.depth) {
    std::filesystem::path depth_path = options.output;
    depth_path.replace_filename(depth_path.stem().string() + "_depth.png");
    cv::Mat depth16;
    depth.convertTo(depth16, CV_16U, 65535.0 / (3.3 - 2.25), -2.25 * 65535.0 / (3.3 - 2.25));
    SaveImage(depth_path, depth16);
    std::cout << " and its depth to '" << depth_path.string() << "'";
  }
  std::cout << " in " << timer.Seconds() << " s.\n";
  return kExitOk;
}

int RunRender(const std::vector<std::string>& args) {
  return GuardedRun("render", [&] {
    RenderCommandOptions options;
    std::vector<std::string> positionals;
    if (!ParseCommand(options, args,
                      "avatar-studio render FILE.avatar [--yaw D --pitch D --roll D] [--expr name=value ...] "
                      "[--mode preview|standard|final] -o out.png [--alpha] [--depth]",
                      "Renders one frame of an avatar from a camera and an expression.", &positionals)) {
      return kExitOk;
    }
    AVATAR_CHECK_OPTION(positionals.size() <= 1)
        << "expected one FILE.avatar, got " << positionals.size() << " arguments";
    if (!positionals.empty()) options.input = positionals[0];
    return RunRenderImpl(options, ProcessContext());
  });
}

AVATAR_REGISTER_COMMAND("render", "render an avatar from a camera and expression", RunRender);

}  // namespace avatar::app
