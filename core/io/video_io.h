#pragma once
// Video files in and out, frame by frame in constant memory, with clear errors.

#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace avatar {

struct VideoInfo {
  int width = 0;           // Frame width in pixels.
  int height = 0;          // Frame height in pixels.
  double fps = 0.0;        // Frames per second as declared by the container.
  int64_t frame_count = 0; // Declared number of frames (may be an estimate for some files).
  bool has_audio = false;  // True if the container holds an audio stream (probed with ffprobe when available).
};

// Reads a video one frame at a time. Memory use does not grow with the clip's length.
class VideoReader {
 public:
  // Opens `path`. Throws Io (missing/unreadable) or InvalidInput (not a video, no frames),
  // naming the file and what to do.
  explicit VideoReader(const std::filesystem::path& path);
  ~VideoReader();
  VideoReader(const VideoReader&) = delete;
  VideoReader& operator=(const VideoReader&) = delete;

  const VideoInfo& Info() const { return info_; }
  const std::filesystem::path& Path() const { return path_; }
  // Reads the next frame as BGR8 into `frame`; returns false at the end of the clip.
  bool Read(cv::Mat& frame);
  // Index of the next frame Read() returns.
  int64_t NextIndex() const { return next_; }
  // Moves to frame `index` (clamped to the clip); slower than reading on.
  void Seek(int64_t index);

 private:
  struct State;
  std::unique_ptr<State> state_;
  std::filesystem::path path_;
  VideoInfo info_;
  int64_t next_ = 0;
};

// True if `path`'s extension is a video container the app reads (.mp4, .mov, .avi, .mkv, .webm, .m4v).
bool IsVideoPath(const std::filesystem::path& path);

// Whether a media file has an audio stream, via ffprobe (false if ffprobe is unavailable).
bool ProbeHasAudio(const std::filesystem::path& path);

// Copies the audio of `audio_source` into `video` (video stream copied, not re-encoded),
// writing `output` atomically. Throws Io if ffmpeg fails or is missing.
void MuxAudio(const std::filesystem::path& video, const std::filesystem::path& audio_source,
              const std::filesystem::path& output);

// Runs a program with arguments (no shell); returns its exit code, or -1 if it could not
// start. Standard output and error go to `log_file` when given, else are discarded.
int RunProgram(const std::string& program, const std::vector<std::string>& args, const std::string& log_file = {});

}  // namespace avatar
