#include "core/pipeline/driving.h"

#include <algorithm>
#include <cmath>

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

DrivingSample DrivingTransfer::Apply(const FrameMeasurement& m, bool smooth) {
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
    const double a = options_.smoothing;
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

KeyframeDriver::KeyframeDriver(const fs::path& path) {
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
        key.expression[it.key()] = it->get<float>();
      }
    }
    keys_.push_back(std::move(key));
  }
  std::stable_sort(keys_.begin(), keys_.end(), [](const Key& a, const Key& b) { return a.time < b.time; });
  Init(NumberOr(j, "duration", keys_.back().time, path));
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

VideoDriver::VideoDriver(const fs::path& path, std::unique_ptr<FrameAnalyzer> analyzer, const DrivingOptions& options,
                         RunContext& ctx)
    : reader_(std::make_unique<VideoReader>(path)), analyzer_(std::move(analyzer)), transfer_(options) {
  options.Validate();
  if (analyzer_ && options.relative) {
    AVATAR_CHECK_OPTION(options.neutral_frame < reader_->Info().frame_count)
        << "--neutral-frame " << options.neutral_frame << " is past the end of '" << path.string() << "' ("
        << reader_->Info().frame_count << " frames)";
    ctx.Report("analyse neutral frame", 0.0);
    reader_->Seek(options.neutral_frame);
    cv::Mat neutral;
    AVATAR_CHECK_INPUT(reader_->Read(neutral))
        << "cannot read the neutral frame " << options.neutral_frame << " of '" << path.string() << "'";
    FrameMeasurement m = analyzer_->Measure(neutral, ctx);
    AVATAR_CHECK_INPUT(m.face_found) << "no face found in the neutral frame " << options.neutral_frame << " of '"
                                     << path.string() << "'; choose another frame with --neutral-frame";
    transfer_.SetNeutral(m);
    analyzer_->Reset();
    reader_->Seek(0);
  }
}

VideoDriver::~VideoDriver() = default;

double VideoDriver::Fps() const { return reader_->Info().fps; }
int64_t VideoDriver::FrameCount() const { return reader_->Info().frame_count; }
std::string VideoDriver::AudioSource() const { return reader_->Info().has_audio ? reader_->Path().string() : ""; }

bool VideoDriver::Next(DrivingSample& sample, RunContext& ctx) {
  ctx.ThrowIfCancelled();
  if (!reader_->Read(frame_)) return false;
  if (!analyzer_) {
    sample = DrivingSample{};
    return true;
  }
  FrameMeasurement m = analyzer_->Measure(frame_, ctx);
  if (!m.face_found) {
    // Hold the last measured frame so the avatar does not snap to neutral on a missed face.
    if (last_good_.has_value()) {
      m = *last_good_;
      m.face_found = false;
    } else if (transfer_.Neutral().has_value()) {
      m = *transfer_.Neutral();
      m.face_found = false;
    }
  } else {
    last_good_ = m;
  }
  sample = transfer_.Apply(m, true);
  return true;
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
