#pragma once
// Streaming export of rendered frames: an MP4 (H.264 through OpenCV's FFmpeg backend, with
// the driver's audio muxed in by ffmpeg) or a PNG sequence with true alpha. Frames are
// written one at a time (constant memory), into temporary files that are renamed over the
// target only when the whole export succeeded: a cancelled or failed export leaves no file
// under the target name and no temporary files.

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>

#include <opencv2/core.hpp>

#include "core/util/run_context.h"

namespace avatar {

// One frame to export.
struct ExportFrame {
  cv::Mat bgr;    // [H,W] CV_8UC3 colour.
  cv::Mat alpha;  // [H,W] CV_8UC1 opacity (255 = opaque); may be empty (opaque) for MP4.
};

struct ExportOptions {
  // Target: a .mp4 file, or a folder for the PNG sequence.
  std::string output;
  // "mp4" or "png" ("" = from the output's extension: .mp4 -> mp4, otherwise png).
  std::string format;
  // Frames per second of the MP4.
  double fps = 25.0;
  // Media file whose audio is copied into the MP4 ("" = no audio; a file without audio is fine).
  std::string audio_from;

  template <typename V>
  void Visit(V&& v) {
    v("output", output, "Output .mp4 file or PNG folder", 'o');
    v("format", format, "mp4 or png (default: from the output name)");
    v("fps", fps, "Frames per second of the MP4");
    v("audio_from", audio_from, "Copy the audio of this media file into the MP4");
  }
  // Throws InvalidOptions (empty output, unknown format, fps outside (0,240]).
  void Validate() const;
  // The effective format after the extension rule.
  std::string ResolvedFormat() const;
};

// Receives frames in order. Finish() publishes the result; destroying a sink without
// Finish() (an exception or a cancel) removes everything it wrote.
class FrameSink {
 public:
  virtual ~FrameSink() = default;
  // Throws InvalidInput for a frame of the wrong type or size, Io on write errors.
  virtual void Write(const ExportFrame& frame) = 0;
  // Completes the export and renames it into place; throws Io on failure (nothing is left).
  virtual void Finish() = 0;
  virtual int64_t FramesWritten() const = 0;
};

// Opens the sink for `options` (validated here); frames must be `width` x `height`.
std::unique_ptr<FrameSink> OpenFrameSink(const ExportOptions& options, int width, int height);

// Produces frame `index` (0-based) into `frame`; returns false when there are no more.
using FrameProducer = std::function<bool(int64_t index, ExportFrame& frame)>;

struct ExportStats {
  int64_t frames = 0;                // Frames written.
  std::filesystem::path output;      // Where the result is.
};

// Pulls frames from `produce` until it returns false (or `max_frames` > 0 is reached) and
// streams them into a sink. Reports progress as frame i of `expected_frames` (if > 0) and
// stops with Cancelled when ctx is cancelled, leaving nothing behind.
ExportStats ExportFrames(const FrameProducer& produce, int64_t expected_frames, int width, int height,
                         const ExportOptions& options, RunContext& ctx, int64_t max_frames = 0);

}  // namespace avatar
