#include "core/pipeline/driving.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iterator>

#include <nlohmann/json.hpp>

#include "core/io/atomic_file.h"
#include "core/io/video_io.h"
#include "core/util/error.h"

namespace avatar {
namespace fs = std::filesystem;

void DrivingOptions::Validate() const {
  AVATAR_CHECK_OPTION(neutral_frame >= 0) << "--neutral-frame must be >= 0, got " << neutral_frame;
  AVATAR_CHECK_OPTION(std::isfinite(smoothing) && smoothing >= 0.0 && smoothing < 1.0)
      << "--smoothing must be within [0,1), got " << smoothing;
}

DrivingSample DrivingTransfer::Apply(const FrameMeasurement& m, bool smooth, int64_t frames_elapsed) {
  AVATAR_CHECK_INPUT(frames_elapsed >= 1) << "frames_elapsed must be >= 1, got " << frames_elapsed;
  DrivingSample s;
  s.face_found = m.face_found;
  s.pose = m.pose;
  s.expression.coefficients = m.coefficients;
  s.expression.coefficients_absolute = !options_.relative;
  if (options_.relative && neutral_.has_value()) {
    s.pose.yaw -= neutral_->pose.yaw;
    s.pose.pitch -= neutral_->pose.pitch;
    s.pose.roll -= neutral_->pose.roll;
    const auto& n = neutral_->coefficients;
    for (size_t i = 0; i < s.expression.coefficients.size() && i < n.size(); ++i) s.expression.coefficients[i] -= n[i];
  }
  if (smooth && previous_.has_value() && options_.smoothing > 0.0) {
    // Exponential moving average: causal, so it streams with the export.
    const double a = std::pow(options_.smoothing, static_cast<double>(std::min<int64_t>(frames_elapsed, 1000)));
    auto blend = [a](double prev, double now) { return a * prev + (1.0 - a) * now; };
    s.pose.yaw = blend(previous_->pose.yaw, s.pose.yaw);
    s.pose.pitch = blend(previous_->pose.pitch, s.pose.pitch);
    s.pose.roll = blend(previous_->pose.roll, s.pose.roll);
    auto& c = s.expression.coefficients;
    const auto& p = previous_->expression.coefficients;
    if (p.size() == c.size()) {
      for (size_t i = 0; i < c.size(); ++i) c[i] = static_cast<float>(blend(p[i], c[i]));
    }
  }
  if (smooth) previous_ = s;
  return s;
}

// ----------------------------------------------------------------------------- keyframes

namespace {

double NumberOr(const nlohmann::json& j, const char* key, double fallback, const fs::path& file) {
  auto it = j.find(key);
  if (it == j.end()) return fallback;
  if (!it->is_number()) {
    throw InvalidInput("keyframes '" + file.string() + "': field '" + key + "' must be a number");
  }
  const double v = it->get<double>();
  if (!std::isfinite(v)) throw InvalidInput("keyframes '" + file.string() + "': field '" + key + "' is not finite");
  return v;
}

}  // namespace

KeyframeDriver::KeyframeDriver(const fs::path& path) : path_(path) {
  const std::string text = ReadFileBytes(path);
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(text);
  } catch (const nlohmann::json::exception& e) {
    throw InvalidInput("keyframes '" + path.string() + "' is not valid JSON: " + e.what());
  }
  AVATAR_CHECK_INPUT(j.is_object() && j.contains("keys") && j["keys"].is_array() && !j["keys"].empty())
      << "keyframes '" << path.string() << "' must be an object with a non-empty \"keys\" array";
  fps_ = NumberOr(j, "fps", 25.0, path);
  AVATAR_CHECK_INPUT(fps_ > 0.0 && fps_ <= 240.0) << "keyframes '" << path.string() << "': fps must be in (0,240]";
  for (const auto& k : j["keys"]) {
    AVATAR_CHECK_INPUT(k.is_object()) << "keyframes '" << path.string() << "': every key must be an object";
    Key key;
    key.time = NumberOr(k, "time", 0.0, path);
    key.pose.yaw = NumberOr(k, "yaw", 0.0, path);
    key.pose.pitch = NumberOr(k, "pitch", 0.0, path);
    key.pose.roll = NumberOr(k, "roll", 0.0, path);
    key.pose.zoom = NumberOr(k, "zoom", 1.0, path);
    AVATAR_CHECK_INPUT(key.time >= 0.0 && key.pose.zoom > 0.0)
        << "keyframes '" << path.string() << "': time must be >= 0 and zoom > 0";
    if (k.contains("expression")) {
      AVATAR_CHECK_INPUT(k["expression"].is_object())
          << "keyframes '" << path.string() << "': \"expression\" must map control names to numbers";
      for (auto it = k["expression"].begin(); it != k["expression"].end(); ++it) {
        AVATAR_CHECK_INPUT(it->is_number())
            << "keyframes '" << path.string() << "': expression '" << it.key() << "' must be a number";
        const double value = it->get<double>();
        AVATAR_CHECK_INPUT(std::isfinite(value) && std::abs(value) <= 1e3)
            << "keyframes '" << path.string() << "': expression '" << it.key() << "' is " << value
            << "; controls are weights of about 0..1 (at most 1000 in magnitude)";
        key.expression[it.key()] = static_cast<float>(value);
      }
    }
    keys_.push_back(std::move(key));
  }
  std::stable_sort(keys_.begin(), keys_.end(), [](const Key& a, const Key& b) { return a.time < b.time; });
  const double duration = NumberOr(j, "duration", keys_.back().time, path);
  try {
    Init(duration);
  } catch (const InvalidInput& e) {
    throw InvalidInput("keyframes '" + path.string() + "': " + e.what());
  }
}

void KeyframeDriver::CheckControls(const std::vector<std::string>& known) const {
  for (const Key& key : keys_) {
    for (const auto& [name, value] : key.expression) {
      (void)value;
      if (std::find(known.begin(), known.end(), name) != known.end()) continue;
      std::string list;
      for (const auto& k : known) list += (list.empty() ? "" : ", ") + k;
      const std::string where = path_.empty() ? std::string("keyframes") : "keyframes '" + path_.string() + "'";
      throw InvalidInput(where + ": unknown expression control '" + name + "' at " + std::to_string(key.time) +
                         " s; known controls: " + (list.empty() ? std::string("none") : list));
    }
  }
}

KeyframeDriver::KeyframeDriver(std::vector<Key> keys, double fps, double duration) : keys_(std::move(keys)), fps_(fps) {
  AVATAR_CHECK_INPUT(!keys_.empty() && fps_ > 0.0) << "keyframes need at least one key and fps > 0";
  std::stable_sort(keys_.begin(), keys_.end(), [](const Key& a, const Key& b) { return a.time < b.time; });
  Init(duration);
}

void KeyframeDriver::Init(double duration) {
  AVATAR_CHECK_INPUT(std::isfinite(duration) && duration >= 0.0 && duration <= 3600.0)
      << "keyframe duration must be within 0..3600 s, got " << duration;
  // Frames at t = 0, 1/fps, ..., duration (inclusive), at least one.
  frames_ = std::max<int64_t>(1, static_cast<int64_t>(std::floor(duration * fps_ + 1e-9)) + 1);
}

DrivingSample KeyframeDriver::At(double time) const {
  // Bracketing keys: before the first or after the last key, that key is held.
  size_t hi = 0;
  while (hi < keys_.size() && keys_[hi].time <= time) ++hi;
  const Key& from = keys_[hi == 0 ? 0 : hi - 1];
  const Key& to = keys_[std::min(hi, keys_.size() - 1)];
  const double span = to.time - from.time;
  const double t = span > 0.0 ? std::clamp((time - from.time) / span, 0.0, 1.0) : 0.0;
  auto lerp = [t](double x, double y) { return x + (y - x) * t; };
  DrivingSample s;
  s.pose.yaw = lerp(from.pose.yaw, to.pose.yaw);
  s.pose.pitch = lerp(from.pose.pitch, to.pose.pitch);
  s.pose.roll = lerp(from.pose.roll, to.pose.roll);
  s.pose.zoom = lerp(from.pose.zoom, to.pose.zoom);
  auto get = [](const Key& key, const std::string& name) {
    auto it = key.expression.find(name);
    return it == key.expression.end() ? 0.0 : double(it->second);
  };
  for (const Key* k : {&from, &to}) {
    for (const auto& entry : k->expression) {
      s.expression.controls[entry.first] = static_cast<float>(lerp(get(from, entry.first), get(to, entry.first)));
    }
  }
  return s;
}

bool KeyframeDriver::Next(DrivingSample& sample, RunContext& ctx) {
  ctx.ThrowIfCancelled();
  if (next_ >= frames_) return false;
  sample = At(static_cast<double>(next_) / fps_);
  ++next_;
  return true;
}

// ----------------------------------------------------------------------------- video

DrivingVideo::DrivingVideo(const fs::path& path, std::unique_ptr<FrameAnalyzer> analyzer, const DrivingOptions& options,
                           RunContext& ctx)
    : reader_(std::make_unique<VideoReader>(path)), analyzer_(std::move(analyzer)), options_(options), transfer_(options) {
  SetOptions(options, ctx);
}

DrivingVideo::~DrivingVideo() = default;

double DrivingVideo::Fps() const { return reader_->Info().fps; }
int64_t DrivingVideo::FrameCount() const { return reader_->Info().frame_count; }
const fs::path& DrivingVideo::Path() const { return reader_->Path(); }
bool DrivingVideo::HasAudio() const { return reader_->Info().has_audio; }

const FrameMeasurement& DrivingVideo::Measure(int64_t index, RunContext& ctx, cv::Mat* frame_out, bool* read_ok) {
  static const FrameMeasurement kNone;
  *read_ok = false;
  auto cached = measured_.find(index);
  if (cached != measured_.end() && frame_out == nullptr) {
    *read_ok = true;
    return cached->second;
  }
  // Past the declared end only when reading on (a declared count may be an estimate);
  // Seek() would clamp to the last frame instead.
  if (index >= FrameCount() && reader_->NextIndex() != index) return kNone;
  if (reader_->NextIndex() != index) reader_->Seek(index);
  cv::Mat frame;
  if (!reader_->Read(frame)) return kNone;
  *read_ok = true;
  if (frame_out != nullptr) *frame_out = frame;
  if (cached != measured_.end()) return cached->second;
  FrameMeasurement m;
  if (analyzer_) {
    // The analyser (a tracker) sees frames in order: anything but the next frame restarts it.
    // This depends only on which frames were measured, so every caller gets the same values.
    if (index != last_measured_ + 1) analyzer_->Reset();
    m = analyzer_->Measure(frame, ctx);
    last_measured_ = index;
  }
  if (measured_.size() >= kMaxCachedFrames) {
    // Forget the measurement farthest from this frame.
    const int64_t lo = measured_.begin()->first;
    const int64_t hi = measured_.rbegin()->first;
    measured_.erase(index - lo > hi - index ? measured_.begin() : std::prev(measured_.end()));
  }
  return measured_.emplace(index, std::move(m)).first->second;
}

std::optional<int64_t> DrivingVideo::FirstFaceFrom(int64_t from, RunContext& ctx) {
  const int64_t end = std::min(FrameCount(), from + kNeutralSearchFrames);
  for (int64_t i = from; i < end; ++i) {
    if (i > from) {
      ctx.Report("look for a face in the driving video", static_cast<double>(i - from) / static_cast<double>(end - from),
                 "frame " + std::to_string(i));
    }
    bool ok = false;
    const FrameMeasurement& m = Measure(i, ctx, nullptr, &ok);
    if (!ok) break;
    if (m.face_found) return i;
  }
  return std::nullopt;
}

std::optional<int64_t> DrivingVideo::LastFaceBefore(int64_t index, RunContext& ctx) {
  // Measured forward in short runs (decoding backwards frame by frame would seek every time),
  // searched backwards.
  constexpr int64_t kRun = 25;
  const int64_t stop = std::max<int64_t>(0, index - kNeutralSearchFrames);
  for (int64_t end = index; end > stop; end -= kRun) {
    const int64_t begin = std::max<int64_t>(stop, end - kRun);
    for (int64_t i = begin; i < end; ++i) {
      bool ok = false;
      Measure(i, ctx, nullptr, &ok);
    }
    for (int64_t i = end - 1; i >= begin; --i) {
      auto it = measured_.find(i);
      if (it != measured_.end() && it->second.face_found) return i;
    }
  }
  return std::nullopt;
}

DrivingVideo::Choice DrivingVideo::ChooseReference(const DrivingOptions& options, RunContext& ctx) {
  Choice c;
  if (!analyzer_) return c;
  const int64_t count = FrameCount();
  const std::string name = Path().filename().string();
  if (options.relative) {
    AVATAR_CHECK_OPTION(options.neutral_frame < count)
        << "--neutral-frame " << options.neutral_frame << " is past the end of '" << Path().string() << "' ("
        << count << " frames: 0.." << count - 1 << ")";
  }
  const int64_t from = options.relative ? options.neutral_frame : 0;
  ctx.Report("analyse neutral frame", 0.0, "frame " + std::to_string(from));
  const std::optional<int64_t> found = FirstFaceFrom(from, ctx);
  if (!found.has_value()) {
    if (!options.relative) return c;  // Absolute: nothing to hold before a face; frames stay neutral.
    const int64_t last = std::min(count, from + kNeutralSearchFrames) - 1;
    throw InvalidInput("no face found in '" + Path().string() + "' from the neutral frame " + std::to_string(from) +
                       " to frame " + std::to_string(last) +
                       "; choose a driving video that shows a face, or another neutral frame (--neutral-frame)");
  }
  c.index = *found;
  c.measurement = measured_.at(*found);
  if (options.relative && *found != from) {
    char seconds[32];
    std::snprintf(seconds, sizeof(seconds), "%.2f", Fps() > 0.0 ? static_cast<double>(*found) / Fps() : 0.0);
    c.note = "the neutral frame " + std::to_string(from) + " of '" + name + "' shows no face; using frame " +
             std::to_string(*found) + " (" + seconds + " s), the first frame with a face, as the neutral frame";
  }
  return c;
}

void DrivingVideo::SetOptions(const DrivingOptions& options, RunContext& ctx) {
  options.Validate();
  Choice c = ChooseReference(options, ctx);
  options_ = options;
  transfer_ = DrivingTransfer(options);
  if (options.relative && c.measurement.has_value()) transfer_.SetNeutral(*c.measurement);
  neutral_index_ = options.relative ? c.index : -1;
  neutral_note_ = std::move(c.note);
  fallback_ = std::move(c.measurement);
  last_index_ = -2;
  last_good_.reset();
}

bool DrivingVideo::At(int64_t index, DrivingSample& sample, RunContext& ctx, cv::Mat* frame_out) {
  ctx.ThrowIfCancelled();
  if (index < 0) return false;
  bool ok = false;
  FrameMeasurement m = Measure(index, ctx, frame_out, &ok);
  if (!ok) return false;
  if (!analyzer_) {
    sample = DrivingSample{};
    last_index_ = index;
    return true;
  }
  if (index != last_index_ + 1) {
    // A jump: smoothing restarts, and the held measurement is looked up afresh.
    transfer_.ResetHistory();
    last_good_.reset();
    if (!m.face_found) {
      if (const std::optional<int64_t> j = LastFaceBefore(index, ctx)) last_good_ = measured_.at(*j);
    }
  }
  if (m.face_found) {
    last_good_ = m;
  } else {
    // Hold the last measured face so the avatar does not snap on a missed face.
    if (last_good_.has_value()) {
      m = *last_good_;
    } else if (fallback_.has_value()) {
      m = *fallback_;
    }
    m.face_found = false;
  }
  sample = transfer_.Apply(m, true);
  last_index_ = index;
  return true;
}

VideoDriver::VideoDriver(const fs::path& path, std::unique_ptr<FrameAnalyzer> analyzer, const DrivingOptions& options,
                         RunContext& ctx)
    : video_(path, std::move(analyzer), options, ctx) {}

VideoDriver::~VideoDriver() = default;

double VideoDriver::Fps() const { return video_.Fps(); }
int64_t VideoDriver::FrameCount() const { return video_.FrameCount(); }
std::string VideoDriver::AudioSource() const { return video_.HasAudio() ? video_.Path().string() : ""; }

bool VideoDriver::Next(DrivingSample& sample, RunContext& ctx) {
  if (!video_.At(next_, sample, ctx)) return false;
  ++next_;
  return true;
}

// ----------------------------------------------------------------------------- composition

ViewPose ComposeView(const ViewPose& source_pose, const ViewPose& user_view, const ViewPose* driver_pose) {
  ViewPose v = source_pose;
  v.yaw += user_view.yaw;
  v.pitch += user_view.pitch;
  v.roll += user_view.roll;
  if (driver_pose != nullptr) {
    v.yaw += driver_pose->yaw;
    v.pitch += driver_pose->pitch;
    v.roll += driver_pose->roll;
  }
  v.zoom = user_view.zoom;
  return v;
}

FrameExpression ComposeExpression(const FrameExpression& user, const DrivingSample* sample) {
  FrameExpression e = user;
  if (sample != nullptr) {
    e.coefficients = sample->expression.coefficients;
    e.coefficients_absolute = sample->expression.coefficients_absolute;
    for (const auto& [name, value] : sample->expression.controls) e.controls[name] += value;
  }
  for (auto& entry : e.controls) entry.second = std::clamp(entry.second, 0.0f, 1.0f);
  return e;
}

FrameRequest ComposeFrame(const ViewPose& source_pose, const ViewPose& user_view, const FrameExpression& user_expression,
                          const DrivingSample* sample, bool follow_driver_pose, int width, int height) {
  FrameRequest r;
  r.width = width;
  r.height = height;
  r.view = ComposeView(source_pose, user_view, follow_driver_pose && sample != nullptr ? &sample->pose : nullptr);
  r.expression = ComposeExpression(user_expression, sample);
  return r;
}

std::unique_ptr<Driver> OpenDriver(const fs::path& path, const FrameAnalyzerFactory& analyzers,
                                   const DrivingOptions& options, RunContext& ctx) {
  std::string ext = path.extension().string();
  for (auto& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (ext == ".json") return std::make_unique<KeyframeDriver>(path);
  AVATAR_CHECK_INPUT(IsVideoPath(path))
      << "driver '" << path.string()
      << "' is neither a video (.mp4, .mov, .avi, .mkv, .webm, .m4v) nor keyframes (.json)";
  std::unique_ptr<FrameAnalyzer> analyzer = analyzers ? analyzers(ctx) : nullptr;
  return std::make_unique<VideoDriver>(path, std::move(analyzer), options, ctx);
}

}  // namespace avatar
