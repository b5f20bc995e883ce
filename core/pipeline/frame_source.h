#pragma once
// What the studio's viewport and every export render: a "frame source" turns a camera pose
// and an expression into one image with opacity. The GUI, `avatar-studio animate` and the
// export dialog all render through this one interface, so swapping what stands behind it
// (the plain portrait, the morphable-model preview, the neural session) touches no caller.
//
// Honesty rule: a source renders what it says in Label(); nothing is passed off as the
// neural avatar unless the neural network produced it.

#include <array>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

#include "core/pipeline/expression.h"
#include "core/render/view_pose.h"
#include "core/util/run_context.h"

namespace avatar {

// The head pose a frame shows: the project's one pose type, render::ViewPose
// (core/render/view_pose.h: yaw, pitch, roll, zoom). render::CameraForView turns it into the
// camera that renders it; that is the one pose conversion of a frame.
using render::CameraLabel25;
using render::ViewPose;

// The expression of a frame: core/pipeline's one expression type (expression.h), under the
// name the frame-source code has always used.
using FrameExpression = Expression;

// One render request.
struct FrameRequest {
  ViewPose view;               // Camera.
  FrameExpression expression;  // Expression.
  int width = 512;             // Output width in pixels.
  int height = 512;            // Output height in pixels.
};

// One rendered frame.
struct RenderedFrame {
  cv::Mat bgr;    // [H,W] CV_8UC3 colour on black.
  cv::Mat alpha;  // [H,W] CV_8UC1 opacity of the head (255 = opaque).
  cv::Mat depth;  // [H,W] CV_32FC1 depth along the ray (inf where empty); may be empty.
  // Optional overlays in output pixels: projected face landmarks and mesh triangles
  // (indices into `vertices`). Empty when the source has no geometry.
  std::vector<cv::Point2f> landmarks;
  std::vector<cv::Point2f> vertices;
  std::vector<cv::Vec3i> triangles;
  // What ran for this frame, for the status bar: "" = everything (the full frame), else e.g.
  // "face update" for a quick frame (FrameSource::RenderQuick).
  std::string stages;
};

// What the source panel draws over the portrait thumbnail (portrait pixel coordinates).
struct SourceOverlay {
  std::vector<cv::Rect2f> faces;       // Detected face boxes.
  std::vector<cv::Point2f> landmarks;  // Landmarks of the face used.
};

class FrameSource {
 public:
  virtual ~FrameSource() = default;
  // What this source shows, for the viewport and the status bar, e.g.
  // "Preview: morphable model (neural model not trained yet)".
  virtual std::string Label() const = 0;
  // True when yaw/pitch/roll/zoom change the picture.
  virtual bool SupportsPose() const = 0;
  // Names of the expression controls that change the picture (may be empty).
  virtual std::vector<std::string> ExpressionControls() const = 0;
  // Length of FrameExpression::coefficients this source understands (0 = none).
  virtual int CoefficientCount() const { return 0; }
  // The portrait's own head pose, for the "source pose" export view.
  virtual ViewPose SourcePose() const { return {}; }
  // Detection and landmarks measured on the portrait (empty when not analysed).
  virtual SourceOverlay Overlay() const { return {}; }
  // Renders one frame. Checks ctx for cancel but does not Report() (exports report per
  // frame). Must be safe to call from one worker thread at a time while the
  // GUI thread holds the object (const, no hidden shared mutable state without a lock).
  // Throws InvalidOptions for sizes outside 16..4096, Cancelled through ctx.
  virtual RenderedFrame Render(const FrameRequest& request, RunContext& ctx) const = 0;
  // A frame of `request` made at once from work kept from an earlier Render (the photo's detail
  // path: a new expression over the last network frame of the same view), its `stages` saying
  // so; nullopt when the source keeps nothing that serves (the default). The viewport shows it
  // first and then renders the full frame (ui/preview_worker.h).
  virtual std::optional<RenderedFrame> RenderQuick(const FrameRequest& request, RunContext& ctx) const {
    (void)request;
    (void)ctx;
    return std::nullopt;
  }
  // The frame source this one draws over (the photo's detail path wraps the neural avatar),
  // or null for a source that renders by itself.
  virtual std::shared_ptr<const FrameSource> Wrapped() const { return nullptr; }

  // What the user should know about the result, found while building the source (e.g. a small
  // face: the avatar will be soft); one sentence each, empty when all is well.
  const std::vector<std::string>& Warnings() const { return warnings_; }
  void SetWarnings(std::vector<std::string> warnings) { warnings_ = std::move(warnings); }

 private:
  std::vector<std::string> warnings_;
};

// Today's minimal source: the portrait itself, letterboxed like the viewport, fully opaque
// where the photo is. It has no 3D: pose and expression do not change it, and its label
// says so.
class PortraitFrameSource : public FrameSource {
 public:
  // `bgr` is the loaded portrait (CV_8UC3, not empty).
  explicit PortraitFrameSource(cv::Mat bgr);
  std::string Label() const override;
  bool SupportsPose() const override { return false; }
  std::vector<std::string> ExpressionControls() const override { return {}; }
  RenderedFrame Render(const FrameRequest& request, RunContext& ctx) const override;

 private:
  cv::Mat portrait_;
};

// Throws InvalidOptions unless 16 <= width, height <= 4096.
void ValidateFrameSize(int width, int height);

// The source that renders under every wrapper of `source` (Wrapped() followed to the end).
const FrameSource& Unwrapped(const FrameSource& source);

}  // namespace avatar
