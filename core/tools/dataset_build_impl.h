#pragma once
// Private to core/tools (not installed, not for other layers): the state and stages of one dataset
// build (dataset_build.h), shared by its sources:
//   dataset_build.cc            entry points (options, whitelist, BuildDataset), Builder set-up
//   dataset_build_items.cc      stage 1: per-photo and per-clip analysis into items/ID.json
//   dataset_build_finish.cc     stage 2: records, identities, split, pairs, outputs and shards
//   dataset_build_synthetic.cc  stage 2b: synthetic heads of the training photos and their pairs
// avatar::dataset is an internal namespace, hence the aliases below.

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <torch/torch.h>

#include "core/face/face_analyzer.h"
#include "core/morphable/morphable.h"
#include "core/tools/dataset_build.h"
#include "core/util/progress_line.h"
#include "core/util/run_context.h"

namespace avatar::dataset {

namespace fs = std::filesystem;
using nlohmann::json;

// The aligned crop, fit and texture are computed at the analyser's crop size (512), as at inference.
constexpr int kCropSize = 512;
// Stage name of the per-item progress reports (tests count them to cancel after N items).
constexpr const char* kItemStage = "dataset item";

// Shared helpers, each defined once (in the source named).
// Writes `j` atomically, one space of indent (dataset_build.cc).
void WriteJson(const fs::path& path, const json& j);
// A float image in [0,1] as 8 bits (dataset_build_items.cc).
cv::Mat ToU8(const cv::Mat& f);
// A frame index as 5 digits, zero-padded (dataset_build_items.cc).
std::string Pad(int64_t index);
// Euclidean distance of two records' expression coefficients (dataset_build_finish.cc).
double ExpressionDistance(const json& a, const json& b);

// Progress with an ETA on stderr plus ctx reports; one Step() per finished item.
class ProgressMeter {
 public:
  ProgressMeter(RunContext& ctx, bool print, int total) : ctx_(ctx), print_(print), total_(std::max(total, 1)) {}
  void Step(const std::string& what, bool computed) {
    ++done_;
    if (computed) ++computed_;
    const double elapsed = std::chrono::duration<double>(Clock::now() - start_).count();
    const double per_item = computed_ > 0 ? elapsed / computed_ : 0.0;
    const double eta = per_item * std::max(0, total_ - done_);
    if (print_) {
      std::ostringstream text;
      text << "[dataset] " << std::min(done_, total_) << "/" << total_ << " items, " << std::fixed
           << std::setprecision(0) << elapsed << " s elapsed, ETA " << eta << " s  " << what.substr(0, 40);
      line_.Update(text.str());
    }
    ctx_.Report(kItemStage, static_cast<double>(done_) / total_, what);
  }
  void Finish() {
    if (print_) line_.Finish();
  }

 private:
  using Clock = std::chrono::steady_clock;
  RunContext& ctx_;
  bool print_;
  ProgressLine line_ = ProgressLine::ForStderr();
  int total_;
  int done_ = 0;
  int computed_ = 0;
  Clock::time_point start_ = Clock::now();
};

// One build into o.out_dir: Photo() and Clip() per input (resumable items), then Finish().
class Builder {
 public:
  // dataset_build.cc: creates the folders and opens build.log.
  Builder(const DatasetBuildOptions& o, RunContext& ctx);

  void Log(const std::string& line);

  // Stage 1 (dataset_build_items.cc).
  // Analyses every face of one photo; returns the ids of the kept faces.
  void Photo(const DatasetPhoto& p, ProgressMeter& meter);
  // Samples, analyses and fits (shared identity) the frames of one clip.
  void Clip(const DatasetClip& c, ProgressMeter& meter);

  // Stage 2 (dataset_build_finish.cc): records, identities, split, pairs and every output file.
  DatasetBuildReport Finish(int photos);

 private:
  // Stage 2b (dataset_build_synthetic.cc).
  // One training photo's head: `views` cameras x 2 mirror groups. Returns the frame records
  // (resumed from items/syn_ID.json when it was rendered with the same views and seed).
  std::vector<json> SyntheticHeadFrames(const json& rec, int views, double* seconds);
  // Renders (or resumes) the heads of the training photos and draws o_.synthetic pairs among
  // the views of each head and mirror group, spread evenly over the heads.
  void Synthetic(const std::vector<json>& records, std::vector<json>* out, json* pairs, DatasetBuildReport* rep);

  // Analysis of stage 1 (dataset_build_items.cc).
  const face::FaceAnalyzer& Analyzer(int face_index);
  face::FaceAnalyzerOptions AnalyzerOptions(int face_index) const;
  cv::Mat Resized(const cv::Mat& m, int interpolation = cv::INTER_AREA) const;
  void SavePortrait(const std::string& id, const face::AlignedPortrait& p);
  // Renders I_exp (texture and identity of `source_fit`, this frame's expression) and I_neu /
  // M_neu (this frame's camera) and returns the record of one frame.
  json Record(const std::string& id, const std::string& kind, const std::string& person, const std::string& package,
              const std::string& file, const morphable::FitResult& fit, const morphable::Texture& tex,
              const morphable::FitResult& source_fit, const face::HeadPose& pose);

  // Shards of stage 2 (dataset_build_finish.cc).
  torch::Tensor LoadU8(const std::string& rel, int channels) const;
  // One split's frames and pairs as a pickled dict of tensors. Returns the number of pairs.
  int WriteShard(const std::string& split, const std::vector<json>& records, const json& pairs,
                 const std::string& file = "");

  const DatasetBuildOptions& o_;
  RunContext& ctx_;
  fs::path dir_;
  const morphable::MorphableModel& model_;
  morphable::RenderOptions render_;
  std::ofstream log_;
  std::vector<std::string> photo_faces_;
  std::map<std::string, std::vector<std::string>> clip_frames_;
  std::map<std::string, std::string> clip_person_;  // clip key -> identity key
  int skipped_ = 0;
};

}  // namespace avatar::dataset
