#include "core/pipeline/export.h"

#include <unistd.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>

#include "core/io/atomic_file.h"
#include "core/io/video_io.h"
#include "core/util/error.h"

namespace avatar {
namespace fs = std::filesystem;

namespace {

// A hidden sibling of `target` for work in progress.
fs::path WorkPath(const fs::path& target, const std::string& suffix) {
  static std::atomic<unsigned> counter{0};
  const fs::path parent = target.parent_path().empty() ? fs::path(".") : target.parent_path();
  return parent / ("." + target.stem().string() + ".part" + std::to_string(::getpid()) + "_" +
                   std::to_string(counter++) + suffix);
}

void CheckFrame(const ExportFrame& frame, int width, int height, bool need_alpha) {
  AVATAR_CHECK_INPUT(frame.bgr.type() == CV_8UC3 && frame.bgr.cols == width && frame.bgr.rows == height)
      << "export frame must be " << width << "x" << height << " BGR8, got " << frame.bgr.cols << "x" << frame.bgr.rows
      << " type " << frame.bgr.type();
  if (!frame.alpha.empty() || need_alpha) {
    AVATAR_CHECK_INPUT(frame.alpha.type() == CV_8UC1 && frame.alpha.size() == frame.bgr.size())
        << "export frame alpha must be " << width << "x" << height << " 8-bit";
  }
}

void RequireParentFolder(const fs::path& target) {
  const fs::path parent = target.parent_path().empty() ? fs::path(".") : target.parent_path();
  std::error_code ec;
  if (!fs::is_directory(parent, ec)) {
    throw Io("cannot export to '" + target.string() + "': folder '" + parent.string() +
             "' does not exist; create it or choose another output");
  }
}

class Mp4Sink : public FrameSink {
 public:
  Mp4Sink(const ExportOptions& options, int width, int height)
      : target_(options.output), audio_(options.audio_from), width_(width), height_(height) {
    RequireParentFolder(target_);
    // H.264 wants even sizes; odd sizes are refused early rather than silently cropped.
    AVATAR_CHECK_INPUT(width % 2 == 0 && height % 2 == 0)
        << "MP4 export needs an even width and height, got " << width << "x" << height;
    CleanStaleWorkFiles(target_);
    work_ = WorkPath(target_, ".mp4");
    writer_.open(work_.string(), cv::CAP_FFMPEG, cv::VideoWriter::fourcc('a', 'v', 'c', '1'), options.fps,
                 cv::Size(width, height));
    if (!writer_.isOpened()) {
      Discard();
      throw Io("cannot create the H.264 video '" + target_.string() +
               "': OpenCV's FFmpeg backend could not open an encoder (is libavcodec with libx264 installed?)");
    }
  }
  ~Mp4Sink() override {
    if (!finished_) Discard();
  }

  void Write(const ExportFrame& frame) override {
    CheckFrame(frame, width_, height_, false);
    writer_.write(frame.bgr);
    ++frames_;
  }

  void Finish() override {
    writer_.release();
    std::error_code ec;
    if (frames_ == 0 || !fs::exists(work_, ec) || fs::file_size(work_, ec) == 0) {
      Discard();
      throw Io("the export to '" + target_.string() + "' produced no video (no frames or disk full)");
    }
    // OpenCV's FFmpeg writer reports no write errors (a full disk gives a truncated file that
    // still "succeeds"), so the finished work file is opened again and its frames counted.
    {
      cv::VideoCapture check(work_.string(), cv::CAP_FFMPEG);
      const double counted = check.isOpened() ? check.get(cv::CAP_PROP_FRAME_COUNT) : -1.0;
      if (std::llround(counted) != frames_) {
        Discard();
        throw Io("writing the video '" + target_.string() + "' failed (" +
                 (counted < 0 ? std::string("the file cannot be read back") :
                                "it holds " + std::to_string(std::llround(counted)) + " of " +
                                    std::to_string(frames_) + " frames") +
                 "); check free disk space");
      }
    }
    try {
      if (!audio_.empty() && ProbeHasAudio(audio_)) {
        MuxAudio(work_, audio_, target_);  // Atomic itself.
        fs::remove(work_, ec);
      } else {
        fs::rename(work_, target_, ec);
        if (ec) throw Io("cannot move the finished video to '" + target_.string() + "': " + ec.message());
      }
    } catch (...) {
      Discard();
      throw;
    }
    finished_ = true;
  }

  int64_t FramesWritten() const override { return frames_; }

 private:
  void Discard() {
    writer_.release();
    std::error_code ec;
    fs::remove(work_, ec);
  }

  fs::path target_;
  fs::path audio_;
  fs::path work_;
  int width_;
  int height_;
  cv::VideoWriter writer_;
  int64_t frames_ = 0;
  bool finished_ = false;
};

// "frames/" and "frames" name the same folder; the work folder is made next to it, so the
// trailing separators go (a path that is only a root stays as it is).
fs::path FolderTarget(const std::string& output) {
  fs::path p(output);
  while (!p.has_filename() && p.has_parent_path() && p != p.root_path()) p = p.parent_path();
  return p;
}

// The file names a PNG-sequence export writes.
bool IsFrameName(const std::string& name) {
  if (name.size() != 16 || name.compare(0, 6, "frame_") != 0 || name.compare(12, 4, ".png") != 0) return false;
  return std::all_of(name.begin() + 6, name.begin() + 12, [](char c) { return c >= '0' && c <= '9'; });
}

// An existing folder is replaced only when it is empty or holds nothing but an earlier export's
// frames: anything else in it is the user's and must not be deleted.
void RequireReplaceableFolder(const fs::path& folder) {
  std::error_code ec;
  for (fs::directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (!it->is_regular_file(ec) || !IsFrameName(name)) {
      throw Io("cannot export a PNG sequence to '" + folder.string() + "': the folder holds '" + name +
               "', which is not a frame of an earlier export; choose an empty or new folder");
    }
  }
  if (ec) throw Io("cannot read the folder '" + folder.string() + "': " + ec.message());
}

class PngSequenceSink : public FrameSink {
 public:
  PngSequenceSink(const ExportOptions& options, int width, int height)
      : target_(FolderTarget(options.output)), width_(width), height_(height) {
    RequireParentFolder(target_);
    CleanStaleWorkFiles(target_);
    std::error_code ec;
    if (fs::exists(target_, ec) && !fs::is_directory(target_, ec)) {
      throw Io("cannot export a PNG sequence to '" + target_.string() + "': a file with that name exists");
    }
    if (fs::is_directory(target_, ec)) RequireReplaceableFolder(target_);
    work_ = WorkPath(target_, ".frames");
    fs::create_directories(work_, ec);
    if (ec) throw Io("cannot create a folder next to '" + target_.string() + "': " + ec.message());
  }
  ~PngSequenceSink() override {
    if (!finished_) {
      std::error_code ec;
      fs::remove_all(work_, ec);
    }
  }

  void Write(const ExportFrame& frame) override {
    CheckFrame(frame, width_, height_, true);
    cv::Mat bgra;
    cv::Mat channels[4];
    cv::split(frame.bgr, channels);
    channels[3] = frame.alpha;
    cv::merge(channels, 4, bgra);
    char name[32];
    std::snprintf(name, sizeof(name), "frame_%06lld.png", static_cast<long long>(frames_));
    bool ok = false;
    try {
      ok = cv::imwrite((work_ / name).string(), bgra);
    } catch (const cv::Exception& e) {
      throw Io("cannot write PNG frame " + std::to_string(frames_) + ": " + e.err);
    }
    if (!ok) throw Io("cannot write PNG frame " + std::to_string(frames_) + " (disk full?)");
    ++frames_;
  }

  void Finish() override {
    AVATAR_CHECK_AS(Io, frames_ > 0) << "the export to '" << target_.string() << "' produced no frames";
    std::error_code ec;
    fs::path old;
    if (fs::exists(target_, ec)) {
      // Replace an earlier export: move it aside, move the new one in, then delete the old.
      old = WorkPath(target_, ".old");
      fs::rename(target_, old, ec);
      if (ec) throw Io("cannot replace '" + target_.string() + "': " + ec.message());
    }
    fs::rename(work_, target_, ec);
    if (ec) {
      if (!old.empty()) fs::rename(old, target_, ec);
      throw Io("cannot move the finished frames to '" + target_.string() + "': " + ec.message());
    }
    finished_ = true;
    if (!old.empty()) fs::remove_all(old, ec);
  }

  int64_t FramesWritten() const override { return frames_; }

 private:
  fs::path target_;
  fs::path work_;
  int width_;
  int height_;
  int64_t frames_ = 0;
  bool finished_ = false;
};

}  // namespace

void ExportOptions::Validate() const {
  AVATAR_CHECK_OPTION(!output.empty()) << "--output is required (a .mp4 file or a folder for PNG frames)";
  AVATAR_CHECK_OPTION(format.empty() || format == "mp4" || format == "png")
      << "--format must be mp4 or png, got '" << format << "'";
  AVATAR_CHECK_OPTION(std::isfinite(fps) && fps > 0.0 && fps <= 240.0) << "--fps must be within (0, 240], got " << fps;
}

std::string ExportOptions::ResolvedFormat() const {
  if (!format.empty()) return format;
  std::string ext = fs::path(output).extension().string();
  for (auto& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return ext == ".mp4" ? "mp4" : "png";
}

std::unique_ptr<FrameSink> OpenFrameSink(const ExportOptions& options, int width, int height) {
  options.Validate();
  AVATAR_CHECK_INPUT(width > 0 && height > 0 && width <= 8192 && height <= 8192)
      << "export size must be within 1..8192, got " << width << "x" << height;
  if (options.ResolvedFormat() == "mp4") return std::make_unique<Mp4Sink>(options, width, height);
  return std::make_unique<PngSequenceSink>(options, width, height);
}

ExportStats ExportFrames(const FrameProducer& produce, int64_t expected_frames, int width, int height,
                         const ExportOptions& options, RunContext& ctx, int64_t max_frames) {
  auto sink = OpenFrameSink(options, width, height);
  ExportFrame frame;
  for (int64_t i = 0; max_frames <= 0 || i < max_frames; ++i) {
    ctx.ThrowIfCancelled();
    if (!produce(i, frame)) break;
    sink->Write(frame);
    const double total = static_cast<double>(max_frames > 0 ? max_frames : expected_frames);
    ctx.Report("export", total > 0 ? (i + 1) / total : 0.0,
               "frame " + std::to_string(i + 1) + (total > 0 ? " of " + std::to_string(int64_t(total)) : ""));
  }
  ctx.ThrowIfCancelled();
  sink->Finish();
  return ExportStats{sink->FramesWritten(), options.output};
}

}  // namespace avatar
