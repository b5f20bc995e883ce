// Stage 1 of the dataset build (dataset_build_impl.h): each photo's faces and each clip's sampled
// frames through the inference preprocessing, into images/, matting/, masks/, exp/, neutral/ and
// one items/ID.json per face.

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <sstream>
#include <string>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "core/face/face_analyzer.h"
#include "core/io/image_io.h"
#include "core/io/json_file.h"
#include "core/io/video_io.h"
#include "core/morphable/morphable.h"
#include "core/pipeline/source_analysis.h"
#include "core/tools/dataset_build_impl.h"
#include "core/util/error.h"

namespace avatar::dataset {
namespace {

// The facematch screenshot is 18 tiles wide.
constexpr int kTileColumns = 18;
// Small tiles are enlarged by this factor before analysis.
constexpr double kTileUpscale = 4.0;

// An input file's name as an item key: letters, digits and '-' kept, the rest '_'.
std::string Sanitize(const std::string& s) {
  std::string out;
  for (char c : s) out += (std::isalnum(static_cast<unsigned char>(c)) || c == '-') ? c : '_';
  return out;
}

// A square around a small face, enlarged so the analyser sees it at a usual size.
cv::Mat CutTile(const cv::Mat& bgr, const cv::Rect2f& box) {
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

}  // namespace

cv::Mat ToU8(const cv::Mat& f) {
  cv::Mat out;
  f.convertTo(out, f.channels() == 1 ? CV_8UC1 : CV_8UC3, 255.0);
  return out;
}

std::string Pad(int64_t index) {
  std::ostringstream s;
  s << std::setw(5) << std::setfill('0') << index;
  return s.str();
}

void Builder::Photo(const DatasetPhoto& p, ProgressMeter& meter) {
  const std::string key = "photo_" + Sanitize(p.package + "_" + fs::path(p.path).filename().string());
  const fs::path marker = dir_ / "items" / (key + ".json");
  if (fs::exists(marker)) {
    const json m = ReadJsonFile(marker, "delete it and rerun the build");
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
      // The inference preprocessing (face analysis, morphable fit, texture), with the build's
      // face thresholds.
      const SourceAnalysis analysis =
          p.tiled ? AnalyseSource(CutTile(bgr, faces[k].box), AnalyzerOptions(-1), ctx_)
                  : AnalyseSource(bgr, AnalyzerOptions(static_cast<int>(k)), ctx_);
      const face::AlignedPortrait& portrait = analysis.portrait;
      const morphable::FitResult& fit = analysis.morphable_fit;
      const morphable::Texture& tex = analysis.texture;
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

void Builder::Clip(const DatasetClip& c, ProgressMeter& meter) {
  const std::string key = "clip_" + Sanitize(c.package + "_" + fs::path(c.path).stem().string());
  const fs::path marker = dir_ / "items" / (key + ".json");
  clip_person_[key] = c.person.empty() ? key : c.person;
  if (fs::exists(marker)) {
    const json m = ReadJsonFile(marker, "delete it and rerun the build");
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
      const json w = ReadJsonFile(work, "delete it and rerun the build");
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

const face::FaceAnalyzer& Builder::Analyzer(int face_index) {
  return face::SharedFaceAnalyzer(AnalyzerOptions(face_index));
}

face::FaceAnalyzerOptions Builder::AnalyzerOptions(int face_index) const {
  face::FaceAnalyzerOptions fa;
  fa.data_dir = o_.data_dir;
  fa.face_index = face_index;
  // The thresholds the training sets were built with (the interactive defaults are looser:
  // 24 px faces, 35 degrees of yaw), so a rebuild gives the same set.
  fa.min_face_px = 48;
  fa.max_abs_yaw = 40.0f;
  return fa;
}

cv::Mat Builder::Resized(const cv::Mat& m, int interpolation) const {
  cv::Mat out;
  cv::resize(m, out, cv::Size(o_.size, o_.size), 0, 0, interpolation);
  return out;
}

void Builder::SavePortrait(const std::string& id, const face::AlignedPortrait& p) {
  SaveImage(dir_ / "images" / (id + ".png"), Resized(p.image_unmatted));
  SaveImage(dir_ / "matting" / (id + ".png"), ToU8(Resized(p.matte)));
  SaveImage(dir_ / "masks" / (id + ".png"), Resized(p.eye_mouth_mask));
}

json Builder::Record(const std::string& id, const std::string& kind, const std::string& person,
                     const std::string& package, const std::string& file, const morphable::FitResult& fit,
                     const morphable::Texture& tex, const morphable::FitResult& source_fit,
                     const face::HeadPose& pose) {
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

}  // namespace avatar::dataset
