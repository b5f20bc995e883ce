#include "core/pipeline/quality.h"

#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <functional>
#include <iomanip>
#include <memory>
#include <optional>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>
#include <torch/torch.h>

#include "core/io/atomic_file.h"
#include "core/io/data_paths.h"
#include "core/model/model_config.h"
#include "core/morphable/fitter.h"
#include "core/morphable/morphable_model.h"
#include "core/pipeline/detail_source.h"
#include "core/pipeline/probe.h"
#include "core/pipeline/session_source.h"
#include "core/pipeline/source_analysis.h"
#include "core/render/camera.h"
#include "core/render/view_pose.h"
#include "core/util/error.h"
#include "core/util/logging.h"
#include "core/util/measure.h"
#include "core/util/options.h"
#include "core/util/threads.h"
#include "core/util/timer.h"

namespace avatar {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr const char* kCacheFormat = "avatar-studio quality estimates";
constexpr int kCacheVersion = 1;

// Render size and samples of a model, from its config (the info's fields when it has none).
struct ModelRender {
  int render_size = 0;
  int num_coarse = 0;
  int num_importance = 0;
  int sr_size = 0;
};

ModelRender RenderOf(const ModelInfo& model) {
  ModelRender r;
  r.render_size = model.render_size;
  r.sr_size = model.sr_size;
  if (!model.config_json.empty()) {
    try {
      const ModelConfig c = ModelConfigFromJson(model.config_json);
      r.render_size = c.render_size;
      r.num_coarse = c.num_coarse;
      r.num_importance = c.num_importance;
      r.sr_size = c.sr_size;
    } catch (const std::exception&) {
      // Described with what the info holds.
    }
  }
  return r;
}

int Scaled(int value, double scale, int minimum) {
  return std::max(minimum, static_cast<int>(std::lround(value * scale)));
}

std::string Seconds(double s) {
  char buf[32];
  if (s >= 100) {
    std::snprintf(buf, sizeof(buf), "%.0f s", s);
  } else if (s >= 10) {
    std::snprintf(buf, sizeof(buf), "%.1f s", s);
  } else {
    std::snprintf(buf, sizeof(buf), "%.2f s", s);
  }
  return buf;
}

std::string Millis(double s) {
  char buf[32];
  if (s >= 1.0) {
    std::snprintf(buf, sizeof(buf), "%.2f s", s);
  } else {
    std::snprintf(buf, sizeof(buf), "%.0f ms", std::max(1.0, s * 1e3));
  }
  return buf;
}

std::string UtcNow() {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  char buf[32];
  std::strftime(buf, sizeof(buf), "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

bool Positive(double v) { return std::isfinite(v) && v > 0.0; }

// The absolute, normalised form of a model path (the path itself when that fails).
std::string CanonicalPath(const std::string& path) {
  if (path.empty()) return path;
  std::error_code ec;
  const fs::path c = fs::weakly_canonical(path, ec);
  return ec ? path : c.string();
}

// Whether the object `entry` has `key` equal to `want`.
bool Has(const json& entry, const char* key, const json& want) {
  if (!entry.is_object()) return false;
  const auto it = entry.find(key);
  return it != entry.end() && *it == want;
}

json EntryJson(const QualityEstimates& e) {
  json j;
  j["model_id"] = e.model_id;
  j["threads"] = e.threads;
  j["checkpoint_path"] = CanonicalPath(e.checkpoint_path);
  j["config_json"] = e.config_json;
  j["measured_at"] = e.measured_at;
  j["ladder"] = e.ladder;
  j["one_shot_seconds"] = e.one_shot_seconds;
  j["refine_setup_seconds"] = e.refine_setup_seconds;
  j["refine_step_seconds"] = e.refine_step_seconds;
  if (!e.checkpoint_path.empty()) {
    std::error_code ec;
    const auto size = fs::file_size(e.checkpoint_path, ec);
    if (!ec) j["checkpoint_size"] = static_cast<int64_t>(size);
    const auto time = fs::last_write_time(e.checkpoint_path, ec);
    if (!ec) j["checkpoint_mtime"] = static_cast<int64_t>(time.time_since_epoch().count());
  }
  // The stored key keeps its first name, "presets" (the cache format is unchanged).
  json levels = json::object();
  for (const auto& p : e.levels) {
    levels[p.level] = {{"reconstruct_seconds", p.reconstruct_seconds},
                       {"frame_seconds", p.frame_seconds},
                       {"detail_frame_seconds", p.detail_frame_seconds}};
  }
  j["presets"] = levels;
  return j;
}

// One cache entry -> estimates; nullopt (with why) for anything malformed.
std::optional<QualityEstimates> EntryFromJson(const json& j, std::string* why) {
  auto fail = [&](const std::string& reason) {
    if (why != nullptr) *why = reason;
    return std::optional<QualityEstimates>();
  };
  if (!j.is_object()) return fail("an entry is not an object");
  QualityEstimates e;
  try {
    e.model_id = j.at("model_id").get<std::string>();
    e.threads = j.at("threads").get<int>();
    e.checkpoint_path = j.value("checkpoint_path", std::string());
    e.config_json = j.value("config_json", std::string());
    e.measured_at = j.value("measured_at", std::string());
    e.ladder = j.at("ladder").get<std::string>();
    e.one_shot_seconds = j.at("one_shot_seconds").get<double>();
    e.refine_setup_seconds = j.at("refine_setup_seconds").get<double>();
    e.refine_step_seconds = j.at("refine_step_seconds").get<double>();
    const json& levels = j.at("presets");  // the quality levels' estimates (stored key, see EntryJson)
    if (!levels.is_object()) return fail("'presets' is not an object");
    for (const auto& p : QualityLadder()) {
      if (!levels.contains(p.name)) return fail("no estimate of quality level '" + p.name + "'");
      QualityEstimate q;
      q.level = p.name;
      q.reconstruct_seconds = levels.at(p.name).at("reconstruct_seconds").get<double>();
      q.frame_seconds = levels.at(p.name).at("frame_seconds").get<double>();
      q.detail_frame_seconds = levels.at(p.name).value("detail_frame_seconds", 0.0);
      if (!(std::isfinite(q.detail_frame_seconds) && q.detail_frame_seconds >= 0.0)) {
        return fail("a bad detail frame time of quality level '" + p.name + "'");
      }
      e.levels.push_back(q);
    }
  } catch (const json::exception& ex) {
    return fail(std::string("malformed entry: ") + ex.what());
  }
  if (e.ladder != QualityLadderFingerprint()) return fail("measured for another version of the ladder");
  if (!e.Complete() || !Positive(e.one_shot_seconds) || !Positive(e.refine_step_seconds) ||
      !(std::isfinite(e.refine_setup_seconds) && e.refine_setup_seconds >= 0.0)) {
    return fail("non-finite or non-positive times");
  }
  return e;
}

// The cache's entries, or an empty list (with why) when the file is missing or malformed.
json ReadEntries(const fs::path& cache, std::string* why) {
  auto fail = [&](const std::string& reason) {
    if (why != nullptr) *why = reason;
    return json::array();
  };
  std::error_code ec;
  if (!fs::exists(cache, ec)) return fail("no cache file " + cache.string());
  json j;
  try {
    j = json::parse(ReadFileBytes(cache));
  } catch (const std::exception& e) {
    return fail(cache.string() + " is not readable JSON: " + e.what());
  }
  if (!j.is_object() || j.value("format", std::string()) != kCacheFormat || !j.contains("entries") ||
      !j["entries"].is_array()) {
    return fail(cache.string() + " is not a quality-estimates cache");
  }
  if (!j.contains("version") || !j["version"].is_number_integer() || j["version"].get<int>() != kCacheVersion) {
    return fail(cache.string() + " has another cache version");
  }
  return j["entries"];
}

}  // namespace

void QualityLevel::Validate() const {
  AVATAR_CHECK_OPTION(!name.empty()) << "a quality level needs a name";
  AVATAR_CHECK_OPTION(std::isfinite(render_scale) && render_scale >= 0.1 && render_scale <= 4.0)
      << "quality level '" << name << "': render_scale must be within 0.1..4, got " << render_scale;
  AVATAR_CHECK_OPTION(std::isfinite(sample_scale) && sample_scale >= 0.1 && sample_scale <= 4.0)
      << "quality level '" << name << "': sample_scale must be within 0.1..4, got " << sample_scale;
  AVATAR_CHECK_OPTION(refine_steps >= 0 && refine_steps <= 100000)
      << "quality level '" << name << "': refine_steps must be within 0..100000, got " << refine_steps;
  AVATAR_CHECK_OPTION(std::isfinite(refine_seconds) && refine_seconds >= 0.0)
      << "quality level '" << name << "': refine_seconds must be >= 0, got " << refine_seconds;
  Refine().Validate();
}

RenderSettings QualityLevel::Render(const ModelInfo& model) const {
  const ModelRender m = RenderOf(model);
  RenderSettings s;
  if (m.render_size > 0) s.resolution = std::min(1024, Scaled(m.render_size, render_scale, 8));
  if (m.num_coarse > 0) s.num_coarse = std::min(512, Scaled(m.num_coarse, sample_scale, 2));
  if (m.num_coarse > 0) s.num_importance = m.num_importance > 0 ? std::min(512, Scaled(m.num_importance, sample_scale, 2)) : 0;
  s.super_resolution = super_resolution;
  return s;
}

RefineOptions QualityLevel::Refine(const RefineOptions& base) const {
  RefineOptions r = base;
  r.steps = refine_steps;
  r.seconds = refine_seconds;
  return r;
}

double QualityLevel::FrameCost(const ModelInfo& model) const {
  const ModelRender m = RenderOf(model);
  const RenderSettings s = Render(model);
  const double side = s.resolution > 0 ? s.resolution : m.render_size;
  const double samples = (s.num_coarse > 0 ? s.num_coarse : m.num_coarse) +
                         (s.num_importance >= 0 ? s.num_importance : m.num_importance);
  return side * side * samples;
}

std::string QualityLevel::Describe(const ModelInfo& model) const {
  const ModelRender m = RenderOf(model);
  const RenderSettings s = Render(model);
  std::ostringstream out;
  if (m.render_size > 0) {
    out << s.resolution << " px";
  } else {
    out << render_scale << "x render";
  }
  if (m.num_coarse > 0) {
    out << ", " << s.num_coarse << "+" << s.num_importance << " samples";
  } else {
    out << ", " << sample_scale << "x samples";
  }
  out << (super_resolution ? (m.sr_size > 0 ? ", SR to " + std::to_string(m.sr_size) + " px" : ", SR") : ", no SR");
  if (refine_steps > 0) out << ", " << refine_steps << " refinement steps";
  if (refine_seconds > 0) out << ", refinement up to " << refine_seconds << " s";
  if (refine_steps == 0 && refine_seconds == 0) out << ", no refinement";
  return out.str();
}

const std::vector<QualityLevel>& QualityLadder() {
  static const std::vector<QualityLevel> ladder = [] {
    std::vector<QualityLevel> l;
    auto add = [&](const char* name, const char* summary, double render, double samples, bool sr, int steps) {
      QualityLevel p;
      p.name = name;
      p.summary = summary;
      p.render_scale = render;
      p.sample_scale = samples;
      p.super_resolution = sr;
      p.refine_steps = steps;
      l.push_back(p);
    };
    add("instant", "half-size render, half the samples: the fastest frames", 0.5, 0.5, false, 0);
    add("preview", "full-size render, half the samples", 1.0, 0.5, false, 0);
    add("standard", "the model's render size and samples, one-shot planes", 1.0, 1.0, false, 0);
    add("fine", "standard + super-resolution + 30 refinement steps on the photo", 1.0, 1.0, true, 30);
    add("best", "twice the samples + super-resolution + 100 refinement steps", 1.0, 2.0, true, 100);
    add("paper", "the published setting: the model's render and samples, super-resolution, no refinement", 1.0, 1.0,
        true, 0);
    for (const auto& p : l) p.Validate();
    return l;
  }();
  return ladder;
}

std::string QualityLevelNames() {
  std::string names;
  for (const auto& p : QualityLadder()) names += (names.empty() ? "" : ", ") + p.name;
  return names;
}

const QualityLevel& QualityLevelByName(const std::string& name) {
  for (const auto& p : QualityLadder()) {
    if (p.name == name) return p;
  }
  throw InvalidOptions("unknown quality level '" + name + "' (" + QualityLevelNames() + ")");
}

std::string QualityLadderFingerprint() {
  json j = json::array();
  for (QualityLevel p : QualityLadder()) {
    p.summary.clear();  // wording changes do not change the times
    j.push_back(options::ToJson(p));
  }
  // What is measured: since 2026-12-06 also each level's frame through the detail path (caches
  // from before are measured again).
  j.push_back("detail frames at " + std::to_string(kQualityDetailSize));
  // FNV-1a of the definitions.
  uint64_t h = 1469598103934665603ull;
  for (const unsigned char c : j.dump()) {
    h ^= c;
    h *= 1099511628211ull;
  }
  char buf[20];
  std::snprintf(buf, sizeof(buf), "%016llx", static_cast<unsigned long long>(h));
  return buf;
}

const QualityEstimate* QualityEstimates::Find(const std::string& level) const {
  for (const auto& p : levels) {
    if (p.level == level) return &p;
  }
  return nullptr;
}

bool QualityEstimates::Complete() const {
  if (ladder != QualityLadderFingerprint()) return false;
  for (const auto& p : QualityLadder()) {
    const QualityEstimate* e = Find(p.name);
    if (e == nullptr || !Positive(e->reconstruct_seconds) || !Positive(e->frame_seconds)) return false;
  }
  return true;
}

std::string FormatQualityEstimate(const QualityEstimate* estimate) {
  if (estimate == nullptr) return "not measured yet";
  std::string text = "reconstruct ~" + Seconds(estimate->reconstruct_seconds) + ", frame " + Millis(estimate->frame_seconds);
  if (estimate->detail_frame_seconds > 0.0) {
    text += ", with detail " + Millis(estimate->detail_frame_seconds) + " at " + std::to_string(kQualityDetailSize) + " px";
  }
  return text;
}

int QualityEstimateThreads() {
  const int configured = ConfiguredThreads();
  return configured > 0 ? configured : at::get_num_threads();
}

fs::path QualityCachePath(const std::string& data_dir) {
  if (const char* env = std::getenv("AVATAR_QUALITY_CACHE"); env != nullptr && *env != '\0') return fs::path(env);
  return DataPaths::Resolve(data_dir).Path("quality-estimates.json");
}

QualityEstimates MeasureQualityEstimates(const Session& session, const RefineOptions& refine_base, RunContext& ctx,
                                         int refine_probe_steps, int repeats) {
  AVATAR_CHECK_OPTION(refine_probe_steps >= 1 && refine_probe_steps <= 100)
      << "refine_probe_steps must be within 1..100, got " << refine_probe_steps;
  AVATAR_CHECK_OPTION(repeats >= 1 && repeats <= 20) << "repeats must be within 1..20, got " << repeats;
  const ModelInfo info = session.Info();
  QualityEstimates e;
  e.model_id = info.model_id;
  e.threads = QualityEstimateThreads();
  e.checkpoint_path = info.checkpoint_path;
  e.config_json = info.config_json;
  e.ladder = QualityLadderFingerprint();

  const std::string stage = "measure quality ladder";
  const face::AlignedPortrait portrait = ProbePortrait();
  int expression_coefficients = 0;
  if (!info.config_json.empty()) {
    const ModelConfig config = ModelConfigFromJson(info.config_json);
    if (config.expression_bases()) expression_coefficients = config.expression_coefficients;
  }
  const SourceFit fit = ProbeFit(expression_coefficients);
  // Progress: reconstruction 0..0.2, refinement 0.2..0.6, frames 0.6..1.
  ctx.Report(stage, 0.0, "one-shot reconstruction");
  Avatar avatar;
  ctx.ThrowIfCancelled();
  e.one_shot_seconds = MedianSeconds(repeats, ctx, [&] {
    RunContext inner;
    avatar = session.ReconstructFromAnalysis(portrait, fit, inner);
  });

  ctx.Report(stage, 0.2, "refinement steps");
  RefineTarget target;
  target.image = portrait.image;
  target.matte = portrait.matte;
  auto refine_seconds = [&](int steps, double begin, double end) {
    RunContext::ProgressRange range(ctx, begin, end);
    RefineOptions o = refine_base;
    o.steps = steps;
    o.seconds = 0.0;
    Timer t;
    RefineAvatar(session, avatar, target, o, ctx);
    return t.Seconds();
  };
  refine_seconds(1, 0.2, 0.27);  // warm-up (loads the perceptual network once per process)
  const double one = refine_seconds(1, 0.27, 0.34);
  const double many = refine_seconds(1 + refine_probe_steps, 0.34, 0.6);
  e.refine_step_seconds = std::max(1e-6, (many - one) / refine_probe_steps);
  e.refine_setup_seconds = std::max(0.0, one - e.refine_step_seconds);

  // The photo's detail path over the probe: a neutral morphable head at the probe's camera (the
  // timing does not depend on the face). Without a morphable model the detail times stay 0.
  std::optional<SourceAnalysis> detail_analysis;
  try {
    const morphable::MorphableModel& model = morphable::LoadDefaultModel(DataPaths::Resolve(refine_base.data_dir));
    morphable::FitResult head = morphable::FitFromLabel(
        morphable::Alpha(static_cast<size_t>(model.num_identity()), 0.0f),
        morphable::Beta(static_cast<size_t>(model.num_expression()), 0.0f), 1.0f, fit.camera, portrait.image.size());
    face::AlignedPortrait probe = portrait;
    probe.image_unmatted = portrait.image;
    probe.image = cv::Mat();
    if (probe.matte.type() != CV_32FC1) probe.matte.convertTo(probe.matte, CV_32FC1);
    detail_analysis = AnalysisFromFit(std::move(probe), std::move(head), refine_base.data_dir);
  } catch (const Error& ex) {
    AVATAR_LOG(kInfo) << "quality estimates without the detail path's times: " << ex.what();
  }
  // Not owned: the frame sources below live inside this call.
  const std::shared_ptr<const Session> shared(&session, [](const Session*) {});

  const auto& ladder = QualityLadder();
  for (size_t i = 0; i < ladder.size(); ++i) {
    const QualityLevel& p = ladder[i];
    ctx.Report(stage, 0.6 + 0.4 * static_cast<double>(i) / static_cast<double>(ladder.size()), "frames: " + p.name);
    const RenderSettings settings = p.Render(info);
    ctx.ThrowIfCancelled();
    const double frame =
        MedianSeconds(repeats, ctx, [&] { session.Animate(avatar, Expression{}, fit.camera, settings); });
    QualityEstimate q;
    q.level = p.name;
    q.frame_seconds = std::max(1e-6, frame);
    const RefineOptions ro = p.Refine(refine_base);
    double refine = 0.0;
    if (ro.Enabled()) {
      refine = e.refine_setup_seconds;
      if (ro.steps > 0) refine += ro.steps * e.refine_step_seconds;
      if (ro.seconds > 0) refine = ro.steps > 0 ? std::min(refine, ro.seconds) : ro.seconds;
    }
    q.reconstruct_seconds = std::max(1e-6, e.one_shot_seconds + refine);
    if (detail_analysis) {
      auto network = std::make_shared<SessionFrameSource>(shared, avatar, false, detail_analysis->overlay);
      network->SetRenderSettings(settings);
      Timer bake;
      const DetailFrameSource detail(std::move(network), *detail_analysis);
      q.reconstruct_seconds += bake.Seconds();
      FrameRequest request;
      request.view = render::PoseOfCamera(fit.camera);
      request.view.yaw += 10.0;  // a new view, as the network's frames
      request.width = request.height = kQualityDetailSize;
      q.detail_frame_seconds =
          std::max(1e-6, MedianSeconds(repeats, ctx, [&] { RunContext inner; detail.Render(request, inner); }));
    }
    e.levels.push_back(q);
  }
  e.measured_at = UtcNow();
  ctx.Report(stage, 1.0, "done");
  return e;
}

std::optional<QualityEstimates> ReadCachedQualityEstimates(const fs::path& cache, const std::string& model_id,
                                                           int threads, std::string* why) {
  std::string reason;
  const json entries = ReadEntries(cache, &reason);
  if (!reason.empty()) {
    if (why != nullptr) *why = reason;
    return std::nullopt;
  }
  for (const auto& entry : entries) {
    if (!Has(entry, "model_id", model_id) || !Has(entry, "threads", threads)) continue;
    return EntryFromJson(entry, why);
  }
  if (why != nullptr) *why = "no estimates of model " + model_id + " at " + std::to_string(threads) + " threads";
  return std::nullopt;
}

std::optional<QualityEstimates> ReadCachedQualityEstimatesForCheckpoint(const fs::path& cache,
                                                                        const fs::path& checkpoint, int threads) {
  std::error_code ec;
  const auto size = fs::file_size(checkpoint, ec);
  if (ec) return std::nullopt;
  const auto time = fs::last_write_time(checkpoint, ec);
  if (ec) return std::nullopt;
  const json entries = ReadEntries(cache, nullptr);
  for (const auto& entry : entries) {
    if (!Has(entry, "checkpoint_path", CanonicalPath(checkpoint.string())) || !Has(entry, "threads", threads) ||
        !Has(entry, "checkpoint_size", static_cast<int64_t>(size)) ||
        !Has(entry, "checkpoint_mtime", static_cast<int64_t>(time.time_since_epoch().count()))) {
      continue;
    }
    return EntryFromJson(entry, nullptr);
  }
  return std::nullopt;
}

void WriteCachedQualityEstimates(const fs::path& cache, const QualityEstimates& estimates) {
  AVATAR_CHECK_INPUT(estimates.Complete()) << "refusing to cache incomplete quality estimates";
  json entries = ReadEntries(cache, nullptr);
  json kept = json::array();
  for (const auto& entry : entries) {
    if (!entry.is_object()) continue;
    if (Has(entry, "model_id", estimates.model_id) && Has(entry, "threads", estimates.threads)) continue;
    kept.push_back(entry);
  }
  kept.push_back(EntryJson(estimates));
  json j;
  j["format"] = kCacheFormat;
  j["version"] = kCacheVersion;
  j["note"] = "Measured time estimates of the quality ladder (core/pipeline/quality.h); safe to delete.";
  j["entries"] = kept;
  std::error_code ec;
  if (cache.has_parent_path()) fs::create_directories(cache.parent_path(), ec);
  WriteBytesAtomically(cache, j.dump(1) + "\n");
}

QualityEstimates CachedOrMeasuredQualityEstimates(const Session& session, const fs::path& cache, RunContext& ctx,
                                                  const RefineOptions& refine_base, bool* measured) {
  const ModelInfo info = session.Info();
  const int threads = QualityEstimateThreads();
  std::string why;
  if (auto cached = ReadCachedQualityEstimates(cache, info.model_id, threads, &why)) {
    if (measured != nullptr) *measured = false;
    return *cached;
  }
  AVATAR_LOG(kInfo) << "measuring the quality ladder on this machine (" << why << ")";
  QualityEstimates e = MeasureQualityEstimates(session, refine_base, ctx);
  try {
    WriteCachedQualityEstimates(cache, e);
  } catch (const Error& ex) {
    AVATAR_LOG(kWarning) << "could not cache the quality estimates: " << ex.what();
  }
  if (measured != nullptr) *measured = true;
  return e;
}

std::string QualityLadderText(const ModelInfo* model, const std::optional<QualityEstimates>& estimates) {
  std::ostringstream out;
  std::vector<std::string> settings;
  size_t width = 0;
  for (const auto& p : QualityLadder()) {
    std::string s = model != nullptr ? p.Describe(*model) : p.Describe(ModelInfo{});
    width = std::max(width, s.size());
    settings.push_back(std::move(s));
  }
  const auto& ladder = QualityLadder();
  for (size_t i = 0; i < ladder.size(); ++i) {
    std::string name = ladder[i].name;
    name.resize(10, ' ');
    std::string s = settings[i];
    s.resize(width + 3, ' ');
    out << "  " << name << s << FormatQualityEstimate(estimates ? estimates->Find(ladder[i].name) : nullptr) << "\n";
  }
  return out.str();
}

std::string QualityLadderHelp(const SessionOptions& model) {
  std::ostringstream out;
  int threads = ConfiguredThreads();
  if (threads <= 0) {
    try {
      threads = ConfigureThreads(0);
    } catch (const Error&) {
      threads = at::get_num_threads();
    }
  }
  fs::path cache;
  std::optional<QualityEstimates> estimates;
  std::string model_name = "no model found";
  try {
    cache = QualityCachePath(model.data_dir);
    std::string origin;
    const fs::path checkpoint = ResolveCheckpoint(model, &origin);
    if (checkpoint.empty()) {
      model_name = "random weights (config " + model.config + ")";
      estimates = ReadCachedQualityEstimates(cache, RandomModelId(model.config, model.seed), threads);
    } else {
      model_name = origin + " model " + checkpoint.filename().string();
      estimates = ReadCachedQualityEstimatesForCheckpoint(cache, checkpoint, threads);
    }
  } catch (const std::exception&) {
    // Help texts never fail: the ladder is listed without estimates.
  }
  out << "Quality levels (--quality NAME), estimates for the " << model_name << " at " << threads
      << " threads on this machine";
  if (!cache.empty()) out << " (measured at first use, cached in " << cache.string() << ")";
  out << ":\n";
  ModelInfo info;
  if (estimates) info.config_json = estimates->config_json;
  out << QualityLadderText(estimates ? &info : nullptr, estimates);
  out << "Reconstruct times cover the network (one-shot forward + refinement); face analysis comes on top.\n";
  return out.str();
}

}  // namespace avatar
