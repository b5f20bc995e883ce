#pragma once
// Animation export shared by `avatar-studio animate` and the studio's export dialog:
// a frame source (what renders the head) + an optional driver (video or keyframes) + a view
// mode -> frames streamed into the exporter (MP4 with the driver's audio, or PNG+alpha),
// one frame at a time in constant memory, atomically (core/pipeline/export.h).

#include <memory>
#include <string>

#include "core/pipeline/driving.h"
#include "core/pipeline/export.h"
#include "core/pipeline/frame_source.h"
#include "core/pipeline/studio_backend.h"
#include "core/util/run_context.h"

namespace avatar {

// How the camera moves during an export.
struct AnimationView {
  // "driver": the driver's head pose (relative to its neutral frame, on top of the source
  // pose, in relative mode); "source": the portrait's pose, fixed; "orbit": a turntable
  // sweep around the source pose.
  std::string mode = "driver";
  // Orbit: peak yaw offset in degrees (the sweep goes +-orbit_degrees).
  double orbit_degrees = 30.0;
  // Zoom applied on top of every frame's pose.
  double zoom = 1.0;

  // Throws InvalidOptions (unknown mode, orbit outside 0..90, zoom outside 0.25..4).
  void Validate() const;
};

// Everything an export needs besides the source and the driver.
struct AnimationPlan {
  AnimationView view;
  // Output frame size in pixels (even numbers for MP4).
  int width = 512;
  int height = 512;
  // Frames per second when there is no video driver (a video driver sets its own rate).
  double fps = 25.0;
  // Clip length in seconds when there is no driver at all (orbit or still clip).
  double seconds = 4.0;
  // Stop after this many frames (0 = the whole driver).
  int64_t max_frames = 0;
  // Expression controls applied to every frame (added to what the driver gives).
  FrameExpression base_expression;
  // Copy the driver video's audio into the MP4.
  bool keep_audio = true;
};

// The camera and expression of frame `index` of `total` of an export, through ComposeFrame
// (driving.h), the composition the studio's preview uses too. `sample` is the driver's
// sample (nullptr without a driver).
FrameRequest PlanFrame(const FrameSource& source, const AnimationPlan& plan, const DrivingSample* sample,
                       bool driver_is_video, int64_t index, int64_t total);

// Streams the animation into `output` (ExportOptions: output path + format; fps and
// audio are filled in here from the plan and the driver). `driver` may be null.
// Throws InvalidOptions, InvalidInput, Io, Cancelled; a failed or cancelled export leaves
// nothing under the target name and no temporary files.
ExportStats ExportAnimation(const FrameSource& source, Driver* driver, const AnimationPlan& plan, ExportOptions output,
                            RunContext& ctx);

// Options of `avatar-studio animate`.
struct AnimateOptions {
  // Portrait photo (the source).
  std::string source;
  // Driving video, or keyframes (.json); "" = none (orbit or a still clip).
  std::string driver;
  // Output .mp4 file or PNG folder.
  std::string output;
  // "mp4" or "png" ("" = from the output name).
  std::string format;
  // Camera: driver, source or orbit.
  std::string view = "driver";
  // Turntable: peak yaw offset in degrees.
  double orbit_degrees = 30.0;
  // Extra zoom on every frame.
  double zoom = 1.0;
  // Output width in pixels.
  int width = 512;
  // Output height in pixels.
  int height = 512;
  // Frames per second without a video driver.
  double fps = 25.0;
  // Clip length in seconds without a driver.
  double seconds = 4.0;
  // Stop after N frames (0 = all).
  int64_t max_frames = 0;
  // Keep the driver's audio.
  bool audio = true;
  // Relative/absolute transfer, neutral frame, smoothing.
  DrivingOptions driving;
  // Which renderer: network size (config), random weights, data folder.
  BackendOptions backend;

  template <typename V>
  void Visit(V&& v) {
    v("source", source, "Portrait photo to animate (or give it as the first argument)");
    v("driver", driver, "Driving video or keyframes .json (or the second argument)");
    v("output", output, "Output .mp4 file or folder for a PNG sequence with alpha", 'o');
    v("format", format, "mp4 or png (default: from the output name)");
    v("view", view, "Camera: driver (driver's head pose), source (portrait's pose) or orbit (turntable)");
    v("orbit_degrees", orbit_degrees, "Turntable: peak yaw offset in degrees");
    v("zoom", zoom, "Extra zoom on every frame");
    v("width", width, "Output width in pixels");
    v("height", height, "Output height in pixels");
    v("fps", fps, "Frames per second without a video driver (a video keeps its own rate)");
    v("seconds", seconds, "Clip length in seconds without a driver");
    v("max_frames", max_frames, "Stop after this many frames (0 = the whole driver)");
    v("audio", audio, "Keep the driver's audio in the MP4 (--no-audio drops it)");
    driving.Visit(v);
    backend.Visit(v);
  }
  // Throws InvalidOptions naming the flag.
  void Validate() const;
  AnimationPlan Plan() const;
};

// What the command did, for its summary line.
struct AnimateResult {
  ExportStats stats;
  std::string source_label;  // FrameSource::Label() of what rendered the frames.
  bool driver_measured = false;
  double fps = 0.0;
  // A video driver's neutral frame (-1: none) and, when it replaced a neutral frame without
  // a face, the sentence saying so ("" otherwise).
  int64_t neutral_frame = -1;
  std::string driver_note;
};

// The whole `animate` command: loads the portrait, builds the frame source (CreateFrameSource),
// opens the driver, exports. Throws like ExportAnimation plus MissingData / ModelLoad.
AnimateResult RunAnimation(const AnimateOptions& options, RunContext& ctx);

}  // namespace avatar
