#include "core/pipeline/frame_source.h"

#include "core/pipeline/portrait_preview.h"
#include "core/util/error.h"

namespace avatar {

void ValidateFrameSize(int width, int height) {
  AVATAR_CHECK_OPTION(width >= 16 && width <= 4096 && height >= 16 && height <= 4096)
      << "frame size must be within 16..4096 pixels, got " << width << "x" << height;
}

PortraitFrameSource::PortraitFrameSource(cv::Mat bgr) : portrait_(std::move(bgr)) {
  AVATAR_CHECK_INPUT(!portrait_.empty() && portrait_.type() == CV_8UC3) << "the portrait must be a BGR8 image";
}

std::string PortraitFrameSource::Label() const { return "Portrait only (no 3D avatar yet)"; }

RenderedFrame PortraitFrameSource::Render(const FrameRequest& request, RunContext& ctx) const {
  ValidateFrameSize(request.width, request.height);
  ctx.ThrowIfCancelled();
  RenderedFrame frame;
  cv::Rect placed;
  frame.bgr = LetterboxImage(portrait_, request.width, request.height, &placed);
  frame.alpha = cv::Mat(request.height, request.width, CV_8UC1, cv::Scalar(0));
  frame.alpha(placed).setTo(255);
  return frame;
}

const FrameSource& Unwrapped(const FrameSource& source) {
  const FrameSource* s = &source;
  while (const std::shared_ptr<const FrameSource> inner = s->Wrapped()) s = inner.get();
  return *s;
}

}  // namespace avatar
