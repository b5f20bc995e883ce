// Stage 2b of the dataset build (dataset_build_impl.h): the synthetic heads of the training photos,
// their rendered views (both mirror groups) and the synthetic pairs among them.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <iomanip>
#include <random>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/io/image_io.h"
#include "core/io/json_file.h"
#include "core/morphable/morphable.h"
#include "core/render/camera.h"
#include "core/tools/dataset_build_impl.h"
#include "core/tools/synthetic_head.h"
#include "core/util/error.h"

namespace avatar::dataset {
namespace {

// Stable across runs and platforms (std::hash is not), for per-head random streams.
uint64_t Fnv1a(const std::string& s) {
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

// A copy of `m`, mirrored left to right when `flip` (the second mirror group).
cv::Mat Flipped(const cv::Mat& m, bool flip) {
  if (!flip) return m.clone();
  cv::Mat out;
  cv::flip(m, out, 1);
  return out;
}

}  // namespace

std::vector<json> Builder::SyntheticHeadFrames(const json& rec, int views, double* seconds) {
  const std::string source_id = rec["id"].get<std::string>();
  const std::string key = "syn_" + source_id;
  const fs::path marker = dir_ / "items" / (key + ".json");
  if (fs::exists(marker)) {
    const json m = ReadJsonFile(marker, "delete it and rerun the build");
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
      morphable::FitFromLabel(rec["alpha"].get<morphable::Alpha>(), rec["beta"].get<morphable::Beta>(),
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

void Builder::Synthetic(const std::vector<json>& records, std::vector<json>* out, json* pairs,
                        DatasetBuildReport* rep) {
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

}  // namespace avatar::dataset
