#include "core/io/video_io.h"

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include <algorithm>
#include <cctype>
#include <cerrno>

#include "core/io/atomic_file.h"
#include "core/util/error.h"

extern char** environ;

namespace avatar {
namespace fs = std::filesystem;

struct VideoReader::State {
  cv::VideoCapture capture;
};

VideoReader::VideoReader(const fs::path& path) : state_(std::make_unique<State>()), path_(path) {
  const std::string name = "'" + path.string() + "'";
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Io("video file not found: " + name + "; check the path");
  if (fs::is_directory(path, ec)) throw Io(name + " is a folder; choose a video file (MP4, MOV, AVI, MKV, WebM)");
  if (fs::file_size(path, ec) == 0) throw InvalidInput("video file " + name + " is empty (0 bytes)");
  try {
    state_->capture.open(path.string(), cv::CAP_FFMPEG);
  } catch (const cv::Exception& e) {
    throw InvalidInput("cannot open video " + name + ": " + e.err);
  }
  if (!state_->capture.isOpened()) {
    throw InvalidInput("cannot open " + name + " as a video: the file is damaged or not a supported format");
  }
  info_.width = static_cast<int>(state_->capture.get(cv::CAP_PROP_FRAME_WIDTH));
  info_.height = static_cast<int>(state_->capture.get(cv::CAP_PROP_FRAME_HEIGHT));
  info_.fps = state_->capture.get(cv::CAP_PROP_FPS);
  info_.frame_count = static_cast<int64_t>(state_->capture.get(cv::CAP_PROP_FRAME_COUNT));
  if (!(info_.fps > 0.0 && info_.fps < 1000.0)) info_.fps = 25.0;  // Missing rate: assume PAL.
  if (info_.width <= 0 || info_.height <= 0 || info_.frame_count <= 0) {
    throw InvalidInput("video " + name + " has no frames; choose another clip");
  }
  info_.has_audio = ProbeHasAudio(path);
}

VideoReader::~VideoReader() = default;

bool VideoReader::Read(cv::Mat& frame) {
  cv::Mat raw;
  try {
    if (!state_->capture.read(raw) || raw.empty()) return false;
  } catch (const cv::Exception& e) {
    throw InvalidInput("cannot decode frame " + std::to_string(next_) + " of '" + path_.string() + "': " + e.err);
  }
  if (raw.type() == CV_8UC3) {
    frame = raw;
  } else if (raw.channels() == 1) {
    cv::cvtColor(raw, frame, cv::COLOR_GRAY2BGR);
  } else if (raw.channels() == 4) {
    cv::cvtColor(raw, frame, cv::COLOR_BGRA2BGR);
  } else {
    throw InvalidInput("video '" + path_.string() + "' has an unsupported pixel format");
  }
  ++next_;
  return true;
}

void VideoReader::Seek(int64_t index) {
  index = std::clamp<int64_t>(index, 0, std::max<int64_t>(0, info_.frame_count - 1));
  state_->capture.set(cv::CAP_PROP_POS_FRAMES, static_cast<double>(index));
  next_ = index;
}

bool IsVideoPath(const fs::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return ext == ".mp4" || ext == ".mov" || ext == ".avi" || ext == ".mkv" || ext == ".webm" || ext == ".m4v";
}

int RunProgram(const std::string& program, const std::vector<std::string>& args, const std::string& log_file) {
  std::vector<std::string> storage;
  storage.push_back(program);
  storage.insert(storage.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& s : storage) argv.push_back(s.data());
  argv.push_back(nullptr);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  const std::string sink = log_file.empty() ? "/dev/null" : log_file;
  posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&actions, 1, sink.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_adddup2(&actions, 1, 2);
  pid_t pid = 0;
  const int rc = posix_spawnp(&pid, program.c_str(), &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (rc != 0) return -1;
  int status = 0;
  while (waitpid(pid, &status, 0) < 0) {
    if (errno != EINTR) return -1;
  }
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

bool ProbeHasAudio(const fs::path& path) {
  const fs::path log = fs::temp_directory_path() / ("avatar_probe_" + std::to_string(::getpid()) + ".txt");
  const int rc = RunProgram("ffprobe", {"-v", "error", "-select_streams", "a", "-show_entries", "stream=codec_type",
                                        "-of", "csv=p=0", path.string()},
                            log.string());
  bool audio = false;
  if (rc == 0) {
    try {
      audio = ReadFileBytes(log).find("audio") != std::string::npos;
    } catch (const Io&) {
      audio = false;
    }
  }
  std::error_code ec;
  fs::remove(log, ec);
  return audio;
}

void MuxAudio(const fs::path& video, const fs::path& audio_source, const fs::path& output) {
  WriteFileAtomically(output, [&](const fs::path& temp) {
    const std::string log = temp.string() + ".log";
    const int rc = RunProgram("ffmpeg", {"-nostdin", "-y", "-v", "error", "-i", video.string(), "-i",
                                         audio_source.string(), "-map", "0:v:0", "-map", "1:a:0", "-c:v", "copy",
                                         "-c:a", "aac", "-shortest", temp.string()},
                              log);
    std::string details;
    try {
      details = ReadFileBytes(log);
    } catch (const Io&) {
    }
    std::error_code ec;
    fs::remove(log, ec);
    if (rc == -1) throw Io("cannot run ffmpeg to add the driver's audio; install the Debian package ffmpeg");
    if (rc != 0) throw Io("ffmpeg could not add the audio of '" + audio_source.string() + "': " + details);
  });
}

}  // namespace avatar
