#include "core/tools/fusion_set.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>
#include <torch/torch.h>

#include "core/io/atomic_file.h"
#include "core/io/json_file.h"
#include "core/pipeline/detail_source.h"
#include "core/pipeline/fusion_input.h"
#include "core/pipeline/source_analysis.h"
#include "core/pipeline/studio_backend.h"
#include "core/render/view_pose.h"
#include "core/tools/dataset_records.h"
#include "core/util/error.h"
#include "core/util/progress_line.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using Clock = std::chrono::steady_clock;

double FusionSetSeconds(Clock::time_point since) { return std::chrono::duration<double>(Clock::now() - since).count(); }

// One source frame and the targets it is rendered at.
struct FusionSourceJob {
  std::string split;
  size_t source = 0;             // index into records
  std::vector<size_t> targets;   // indices into records
  bool photo = false;            // the photo's own view (target = source)
  bool synthetic = false;        // a synthetic head's view (core/tools/synthetic_head.h)
};

// The dataset's pairs grouped into source jobs: per clip the frames with the most pairs first,
// then the synthetic views (training only, at most options.synthetic_sources), then the photos
// (each its own target), per split.
std::vector<FusionSourceJob> PlanFusionJobs(const json& records, const json& pairs, const FusionSetOptions& o) {
  std::map<std::string, size_t> by_id;
  for (size_t i = 0; i < records.size(); ++i) by_id[records[i].value("id", "")] = i;
  // clip -> source -> targets (pairs.json order)
  std::map<std::string, std::map<size_t, std::vector<size_t>>> clips;
  std::map<size_t, std::vector<size_t>> synthetic;     // source -> targets
  std::map<std::string, std::vector<size_t>> photos;  // split -> records
  for (const auto& p : pairs) {
    const auto s = by_id.find(p.value("source", "")), t = by_id.find(p.value("target", ""));
    if (s == by_id.end() || t == by_id.end()) continue;
    const json& rs = records[s->second];
    const std::string kind = p.value("kind", "");
    if (kind == "clip") {
      clips[rs.value("clip", "") + "|" + rs.value("split", "")][s->second].push_back(t->second);
    } else if (kind == "synthetic") {
      synthetic[s->second].push_back(t->second);
    } else if (kind == "photo" && s->second == t->second) {
      photos[rs.value("split", "")].push_back(s->second);
    }
  }
  std::vector<FusionSourceJob> jobs;
  auto add = [&](size_t source, std::vector<size_t> targets, bool is_synthetic) {
    FusionSourceJob j;
    j.source = source;
    j.split = records[source].value("split", "");
    j.targets = std::move(targets);
    j.synthetic = is_synthetic;
    if (static_cast<int>(j.targets.size()) > o.targets_per_source) j.targets.resize(o.targets_per_source);
    jobs.push_back(std::move(j));
  };
  for (auto& [clip, sources] : clips) {
    std::vector<std::pair<size_t, std::vector<size_t>>> ordered(sources.begin(), sources.end());
    std::stable_sort(ordered.begin(), ordered.end(),
                     [](const auto& a, const auto& b) { return a.second.size() > b.second.size(); });
    for (int k = 0; k < std::min<int>(o.sources_per_clip, static_cast<int>(ordered.size())); ++k)
      add(ordered[k].first, ordered[k].second, false);
  }
  if (o.synthetic_sources > 0 && !synthetic.empty()) {
    // An even spread over the synthetic source views (they are grouped by head in id order).
    std::vector<std::pair<size_t, std::vector<size_t>>> all(synthetic.begin(), synthetic.end());
    const size_t n = std::min<size_t>(static_cast<size_t>(o.synthetic_sources), all.size());
    for (size_t k = 0; k < n; ++k) {
      auto& [source, targets] = all[k * all.size() / n];
      if (records[source].value("split", "") == "train") add(source, targets, true);
    }
  }
  for (auto& [split, ids] : photos) {
    // An even spread over the split's photos (pairs.json lists them in build order).
    const size_t n = std::min<size_t>(static_cast<size_t>(std::max(o.photos, 0)), ids.size());
    for (size_t k = 0; k < n; ++k) {
      FusionSourceJob j;
      j.source = ids[k * ids.size() / n];
      j.split = split;
      j.targets = {j.source};
      j.photo = true;
      jobs.push_back(std::move(j));
    }
  }
  return jobs;
}

// The target frame matted onto black at `size`, RGB bytes, and its matte.
std::pair<torch::Tensor, torch::Tensor> FusionTargetBytes(const face::AlignedPortrait& p, int size) {
  cv::Mat crop, matte;
  cv::resize(p.image_unmatted, crop, cv::Size(size, size), 0, 0, cv::INTER_AREA);
  cv::resize(p.matte, matte, cv::Size(size, size), 0, 0, cv::INTER_AREA);
  cv::Mat f, m3, out;
  crop.convertTo(f, CV_32FC3);
  cv::cvtColor(matte, m3, cv::COLOR_GRAY2BGR);
  f = f.mul(m3);
  f.convertTo(out, CV_8UC3);
  return {RgbBytes(out), MaskBytes(matte)};
}

}  // namespace

void FusionSetOptions::Validate() const {
  AVATAR_CHECK_OPTION(!dataset.empty()) << "--data must name a dataset folder (avatar-studio dataset build)";
  AVATAR_CHECK_OPTION(!out_dir.empty()) << "--out must name the fusion set's folder";
  AVATAR_CHECK_OPTION(size >= 32 && size <= 1024 && size % 8 == 0)
      << "--size must be a multiple of 8 within 32..1024, got " << size;
  AVATAR_CHECK_OPTION(sources_per_clip >= 0) << "--sources-per-clip must be >= 0";
  AVATAR_CHECK_OPTION(targets_per_source >= 1) << "--targets-per-source must be >= 1";
  AVATAR_CHECK_OPTION(photos >= 0) << "--photos must be >= 0";
  AVATAR_CHECK_OPTION(synthetic_sources >= 0) << "--synthetic-sources must be >= 0";
}

FusionSetReport BuildFusionSet(const FusionSetOptions& options, RunContext& ctx) {
  options.Validate();
  const auto start = Clock::now();
  const fs::path data(options.dataset), out(options.out_dir);
  const fs::path records_path = data / "records.json", pairs_path = data / "pairs.json";
  AVATAR_CHECK_INPUT(fs::exists(records_path) && fs::exists(pairs_path))
      << options.dataset << " has no records.json / pairs.json: build it with avatar-studio dataset build";
  const json records = ReadJsonFile(records_path, "rebuild the dataset");
  const json pairs = ReadJsonFile(pairs_path, "rebuild the dataset");
  AVATAR_CHECK_INPUT(records.is_array() && pairs.is_array())
      << records_path.string() << " / " << pairs_path.string() << " must hold JSON arrays";
  // Synthetic views (dataset build --synthetic N) join the records, with their head's identity
  // fit (alpha, scale) and the view's camera and expression.
  json all_records = records;
  const fs::path synthetic_path = data / "synthetic.json";
  if (options.synthetic_sources > 0 && fs::exists(synthetic_path)) {
    std::map<std::string, const json*> heads;
    for (const auto& r : records) heads[r.value("id", "")] = &r;
    const json synthetic = ReadJsonFile(synthetic_path, "rebuild the dataset");
    AVATAR_CHECK_INPUT(synthetic.is_array()) << synthetic_path.string() << " must hold a JSON array";
    for (json r : synthetic) {
      const auto head = heads.find(r.value("head", ""));
      if (head == heads.end()) continue;
      r["alpha"] = head->second->at("alpha");
      r["scale"] = head->second->at("scale");
      all_records.push_back(std::move(r));
    }
  }
  const std::vector<FusionSourceJob> jobs = PlanFusionJobs(all_records, pairs, options);
  AVATAR_CHECK_INPUT(!jobs.empty()) << options.dataset << " has no clip or photo pairs to render";
  std::error_code ec;
  for (const char* split : {"train", "val"}) fs::create_directories(out / split, ec);
  if (ec) throw Io(options.out_dir + ": cannot create the fusion set's folders: " + ec.message());

  BackendOptions backend;
  backend.checkpoint = options.checkpoint;
  backend.data_dir = options.data_dir;
  backend.detail = "geometric";  // the set stores the composite's layers: no fusion net per source
  const std::shared_ptr<const Session> session = SharedSession(backend);
  FusionSetReport report;
  report.model = DescribeModel(session->Info());
  std::ofstream log(out / "build.log", std::ios::app);
  ProgressLine progress = ProgressLine::ForStderr();
  const int size = options.size;
  int64_t done = 0, computed = 0;
  double computed_seconds = 0.0;
  for (const FusionSourceJob& job : jobs) {
    ctx.ThrowIfCancelled();
    const json& src = all_records[job.source];
    const std::string sid = src.value("id", "");
    const std::string name = sid + (job.photo ? "_view" : "");
    const fs::path file = out / job.split / (name + ".pt");
    ++done;
    if (!fs::exists(file)) {
      const auto t0 = Clock::now();
      try {
        face::AlignedPortrait portrait = RecordPortrait(data, src);
        morphable::FitResult fit = RecordFit(src, portrait.image_unmatted.size());
        const render::ViewPose source_pose = render::PoseOfCamera(fit.camera);
        SourceAnalysis analysis = AnalysisFromFit(std::move(portrait), std::move(fit), options.data_dir);
        RunContext quiet;
        const PortraitPaths paths = CreatePortraitPaths(std::move(analysis), backend, quiet);
        const auto detail = std::dynamic_pointer_cast<const DetailFrameSource>(paths.detail);
        AVATAR_CHECK_INPUT(detail != nullptr) << "the head detail path is not a detail source";
        std::vector<torch::Tensor> inputs, targets, mattes, previews, metas;
        json listed = json::array();
        for (size_t t : job.targets) {
          ctx.ThrowIfCancelled();
          const json& tgt = all_records[t];
          try {
            FrameRequest request;
            request.width = request.height = size;
            const morphable::CameraLabel target_camera = RecordLabel(tgt.at("label"), tgt.value("id", ""));
            request.view = render::PoseOfCamera(target_camera);
            if (!job.photo) {
              request.expression.coefficients = tgt.at("beta").get<std::vector<float>>();
              request.expression.coefficients_absolute = true;
            }
            const auto r0 = Clock::now();
            const DetailLayers layers = detail->RenderLayers(request, quiet);
            const RenderedFrame preview = paths.preview->Render(request, quiet);
            report.render_seconds += FusionSetSeconds(r0);
            const auto [target, matte] = FusionTargetBytes(RecordPortrait(data, tgt), size);
            inputs.push_back(FusionInputBytes(layers));
            targets.push_back(target);
            mattes.push_back(matte);
            previews.push_back(RgbBytes(preview.bgr));
            double d_expr = 0.0;
            const auto bs = src.at("beta").get<std::vector<float>>(), bt = tgt.at("beta").get<std::vector<float>>();
            for (size_t k = 0; k < std::min(bs.size(), bt.size()); ++k) d_expr += (bt[k] - bs[k]) * (bt[k] - bs[k]);
            metas.push_back(torch::tensor({static_cast<float>(request.view.yaw - source_pose.yaw),
                                           static_cast<float>(request.view.pitch - source_pose.pitch),
                                           static_cast<float>(std::sqrt(d_expr)),
                                           job.photo ? 0.0f : (job.synthetic ? 2.0f : 1.0f)}));
            listed.push_back(tgt.value("id", ""));
          } catch (const Cancelled&) {
            throw;
          } catch (const Error& e) {
            ++report.skipped;
            log << "skip target " << tgt.value("id", "") << " of " << sid << ": " << e.what() << "\n";
          }
        }
        if (!inputs.empty()) {
          const std::vector<torch::Tensor> tensors = {torch::stack(inputs), torch::stack(targets), torch::stack(mattes),
                                                      torch::stack(previews), torch::stack(metas)};
          WriteFileAtomically(file, [&](const fs::path& tmp) { torch::save(tensors, tmp.string()); });
          json info = {{"source", sid},
                       {"targets", listed},
                       {"photo", job.photo},
                       {"synthetic", job.synthetic},
                       {"size", size}};
          WriteBytesAtomically(out / job.split / (name + ".json"), info.dump(1));
        }
        ++computed;
        computed_seconds += FusionSetSeconds(t0);
      } catch (const Cancelled&) {
        throw;
      } catch (const Error& e) {
        ++report.skipped;
        log << "skip source " << sid << ": " << e.what() << "\n";
        std::cerr << "fusion set: skipped source " << sid << ": " << e.what() << "\n";
      }
    }
    const double per = computed > 0 ? computed_seconds / static_cast<double>(computed) : 0.0;
    const double eta = per * static_cast<double>(jobs.size() - done);
    if (options.print_progress) {
      std::ostringstream line;
      line << "fusion set: source " << done << "/" << jobs.size() << " (" << job.split << ")  " << std::fixed
           << std::setprecision(1) << per << " s/source  ETA " << static_cast<int>(eta / 60) << " min";
      progress.Update(line.str());
    }
    ctx.Report("fusion set", static_cast<double>(done) / static_cast<double>(jobs.size()), name);
  }
  progress.Finish();
  // Counts over the whole folder (this run and earlier ones).
  json counts;
  for (const char* split : {"train", "val"}) {
    int64_t samples = 0, sources = 0;
    for (const auto& e : fs::directory_iterator(out / split)) {
      if (e.path().extension() != ".json") continue;
      const json info = ReadJsonFile(e.path(), "delete it and rerun the fusion set build");
      samples += static_cast<int64_t>(info.value("targets", json::array()).size());
      ++sources;
    }
    counts[split] = {{"samples", samples}, {"sources", sources}};
    (std::string(split) == "train" ? report.train_samples : report.val_samples) = samples;
    (std::string(split) == "train" ? report.train_sources : report.val_sources) = sources;
  }
  report.seconds = FusionSetSeconds(start);
  json meta = {{"dataset", fs::absolute(data).string()},
               {"size", size},
               {"sources_per_clip", options.sources_per_clip},
               {"targets_per_source", options.targets_per_source},
               {"photos", options.photos},
               {"synthetic_sources", options.synthetic_sources},
               {"model", report.model},
               {"model_id", session->Info().model_id},
               {"input_channels", "composite RGB, network RGB, face weight, depth weight, face, eye/mouth, opacity"},
               {"counts", counts}};
  WriteBytesAtomically(out / "fusion.json", meta.dump(1));
  return report;
}

}  // namespace avatar
