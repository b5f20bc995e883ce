#pragma once
// The quality ladder: named quality levels that trade waiting for accuracy, from `instant` to
// `best`, plus `paper` (the published setting). One level = how a frame is rendered (render size and
// samples per ray relative to the model's, super-resolution on or off) and how much per-portrait
// refinement (refine.h) follows the one-shot reconstruction. The CLI (`reconstruct --quality`,
// `inspect`, `bench accuracy`) and the studio use this one table.
//
// Time estimates of every level are measured on this machine, the first time a model is used
// with the ladder, and cached as JSON (QualityCachePath) keyed by the model id and the thread
// count. An unreadable, corrupt or foreign cache is measured again, never trusted or fatal.
//
// Estimates cover the network: reconstruct seconds = the one-shot forward (T_c, T_p) plus the
// level's refinement steps (measured seconds per step x steps); frame seconds = one
// Session::Animate at the level's render settings (new view, cached expression). Face analysis
// and the morphable fit of the photo come on top (the same for every level). When the morphable
// model is installed, each level also gets the frame through the photo's detail path (the
// studio's default) at 256 px, and reconstruct seconds add the detail path's bake.

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "core/pipeline/refine.h"
#include "core/pipeline/session.h"
#include "core/util/run_context.h"

namespace avatar {

struct QualityLevel {
  // Name used by --quality and the studio.
  std::string name;
  // One line for help texts.
  std::string summary;
  // Render side as a fraction of the model's render size (0.1..4).
  double render_scale = 1.0;
  // Samples per ray (coarse and importance) as a fraction of the model's (0.1..4).
  double sample_scale = 1.0;
  // Output at the model's SR size (the SR network when trained, else bicubic upsampling).
  bool super_resolution = false;
  // Refinement steps on the source view after the one-shot reconstruction (0 = none).
  int refine_steps = 0;
  // Refinement time budget in seconds (0 = no budget; with steps, whichever ends first).
  double refine_seconds = 0.0;

  template <typename V>
  void Visit(V&& v) {
    v("name", name, "Quality level name");
    v("summary", summary, "What the level is for");
    v("render_scale", render_scale, "Render side as a fraction of the model's render size");
    v("sample_scale", sample_scale, "Samples per ray as a fraction of the model's");
    v("super_resolution", super_resolution, "Output at the SR size");
    v("refine_steps", refine_steps, "Refinement steps after the one-shot reconstruction");
    v("refine_seconds", refine_seconds, "Refinement time budget in seconds (0 = none)");
  }
  // Throws InvalidOptions naming the level.
  void Validate() const;

  // The render settings of this level for a model (its config_json gives render size and samples).
  RenderSettings Render(const ModelInfo& model) const;
  // `base` (loss weights, learning rate, data folder) with this level's steps and budget.
  RefineOptions Refine(const RefineOptions& base = {}) const;
  // Rays x samples per ray of one frame for a model (the ordering key of the ladder).
  double FrameCost(const ModelInfo& model) const;
  // e.g. "32 px, 24+24 samples, no SR, 30 refinement steps" for a model.
  std::string Describe(const ModelInfo& model) const;
};

// instant, preview, standard, fine, best (cheapest to most accurate), then paper.
const std::vector<QualityLevel>& QualityLadder();
// Names in ladder order ("instant, preview, ...") for messages.
std::string QualityLevelNames();
// The level called `name`; throws InvalidOptions listing the names.
const QualityLevel& QualityLevelByName(const std::string& name);
// A short fingerprint of the ladder's definitions (a changed ladder is measured again).
std::string QualityLadderFingerprint();

struct QualityEstimate {
  std::string level;  // QualityLevel::name
  double reconstruct_seconds = 0.0;  // one-shot forward + refinement
  double frame_seconds = 0.0;        // one frame at the level's render settings
  // One frame of the same network render finished by the photo's detail path (detail_source.h,
  // mode head) at kQualityDetailSize px, the studio's interactive output; 0 = not measured (no
  // morphable model installed).
  double detail_frame_seconds = 0.0;
};

// Output side of the detail-path estimates (the studio's interactive frames).
inline constexpr int kQualityDetailSize = 256;

// The estimates of one model on this machine at one thread count.
struct QualityEstimates {
  std::string model_id;          // ModelInfo::model_id
  int threads = 0;               // LibTorch intra-op threads during the measurement
  std::string checkpoint_path;   // ModelInfo::checkpoint_path ("" for random weights)
  std::string config_json;       // ModelInfo::config_json (render size and samples for help texts)
  std::string measured_at;       // UTC, ISO 8601
  std::string ladder;            // QualityLadderFingerprint() at measurement
  double one_shot_seconds = 0.0;      // T_c + T_p forward (median)
  double refine_setup_seconds = 0.0;  // a refinement's fixed cost (targets, first and last evaluation)
  double refine_step_seconds = 0.0;   // one refinement step
  std::vector<QualityEstimate> levels;  // ladder order

  // The level's estimate, or nullptr.
  const QualityEstimate* Find(const std::string& level) const;
  // True when every ladder level has finite positive times and the fingerprint is current.
  bool Complete() const;
};

// "reconstruct ~12.3 s, frame 85 ms" (+ ", with detail 120 ms at 256 px" when measured) or "not
// measured yet" (null).
std::string FormatQualityEstimate(const QualityEstimate* estimate);

// The thread count estimates are keyed by: ConfigureThreads' value, else LibTorch's current one.
int QualityEstimateThreads();

// The cache file: $AVATAR_QUALITY_CACHE when set, else <data folder>/quality-estimates.json
// (DataPaths::Resolve(data_dir)).
std::filesystem::path QualityCachePath(const std::string& data_dir = {});

// Measures the ladder with `session` on a synthetic portrait: the one-shot reconstruction (a
// warm-up, then the median of `repeats`), refinement with `refine_base`'s weights (a warm-up run of
// one step, then runs of 1 and 1 + refine_probe_steps steps: their difference gives the seconds per
// step, the rest the fixed cost), and per level a warm-up frame and the median of `repeats` frames.
// Reports progress ("measure quality ladder"). Throws Cancelled; ModelLoad / MissingData from the
// refinement's perceptual weights when refine_base asks for them and they are not installed.
QualityEstimates MeasureQualityEstimates(const Session& session, const RefineOptions& refine_base, RunContext& ctx,
                                         int refine_probe_steps = 3, int repeats = 2);

// The cached estimates of (model_id, threads) in `cache`, when present, complete and current;
// else nullopt with the reason in `why` (missing file, not JSON, no entry, stale ladder, bad
// values). Never throws for the file's content.
std::optional<QualityEstimates> ReadCachedQualityEstimates(const std::filesystem::path& cache,
                                                           const std::string& model_id, int threads,
                                                           std::string* why = nullptr);
// The cached estimates of the model stored at `checkpoint` (same path, size and modification
// time as when measured) at `threads`, without loading it (for help texts); nullopt otherwise.
std::optional<QualityEstimates> ReadCachedQualityEstimatesForCheckpoint(const std::filesystem::path& cache,
                                                                        const std::filesystem::path& checkpoint,
                                                                        int threads);
// Adds or replaces the entry of (estimates.model_id, estimates.threads), keeping the others
// (a corrupt file is replaced); written atomically. Throws Io naming the file.
void WriteCachedQualityEstimates(const std::filesystem::path& cache, const QualityEstimates& estimates);

// The cached estimates of the session's model, or a fresh measurement (with the default
// refinement weights and refine_base's data folder) written to the cache. A cache that cannot
// be written is logged as a warning (the measurement is still returned). `measured` tells which.
QualityEstimates CachedOrMeasuredQualityEstimates(const Session& session, const std::filesystem::path& cache,
                                                  RunContext& ctx, const RefineOptions& refine_base = {},
                                                  bool* measured = nullptr);

// The ladder as text lines for help and inspect: "  fine      32 px, 24+24 samples, SR, 30
// refinement steps   reconstruct ~4.1 s, frame 21 ms". `model` null: relative settings only.
std::string QualityLadderText(const ModelInfo* model, const std::optional<QualityEstimates>& estimates);

// The ladder for help texts and `inspect`: a heading naming the model and the cache, then
// QualityLadderText with the cached estimates of the model a Session with these options loads
// (default: installed or bundled), looked up by its file without loading it. Never throws.
std::string QualityLadderHelp(const SessionOptions& model = {});

}  // namespace avatar
