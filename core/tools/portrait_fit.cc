#include "core/tools/portrait_fit.h"

#include <filesystem>
#include <optional>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "core/face/face_analyzer.h"
#include "core/io/atomic_file.h"
#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/util/error.h"
#include "core/util/options.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;

void SaveFloatImage(const fs::path& path, const cv::Mat& img) {
  cv::Mat out;
  img.convertTo(out, img.channels() == 1 ? CV_8UC1 : CV_8UC3, 255.0);
  SaveImage(path, out);
}

morphable::FitResult FitOne(const PortraitFitOptions& o, const morphable::MorphableModel& model,
                            const face::AlignedPortrait& portrait, const fs::path& dir) {
  fs::create_directories(dir);
  const cv::Size crop = portrait.image_unmatted.size();
  const morphable::FitResult fit = morphable::Fit(model, portrait.landmarks, crop, o.fit);
  const morphable::Texture tex = morphable::SampleTexture(model, fit, portrait.image_unmatted, o.texture);
  morphable::RenderOptions ro;
  ro.supersample = o.supersample;
  const cv::Size size(o.size, o.size);
  SaveImage(dir / "overlay.png", morphable::DrawFitOverlay(portrait.image_unmatted, model, fit, portrait.landmarks));
  const auto exp_src = morphable::RenderExpressionImage(model, fit, tex, fit.beta, size, ro);
  morphable::Beta edited = fit.beta;
  const morphable::Beta delta = model.ExpressionFromControls(o.edits);
  for (size_t k = 0; k < edited.size(); ++k) edited[k] += delta[k];
  const auto exp_edit = morphable::RenderExpressionImage(model, fit, tex, edited, size, ro);
  const auto neu = morphable::RenderNeutral(model, fit, tex, size, ro);
  SaveFloatImage(dir / "I_exp_source.png", exp_src.image);
  SaveFloatImage(dir / "I_exp_edited.png", exp_edit.image);
  SaveFloatImage(dir / "I_neu.png", neu.image);
  SaveFloatImage(dir / "M_neu.png", neu.mask);
  SaveImage(dir / "crop.png", portrait.image_unmatted);
  // One strip for a quick look: crop | overlay | I_exp source | I_exp edited | I_neu | M_neu.
  {
    const cv::Size tile(256, 256);
    std::vector<cv::Mat> tiles;
    auto add = [&](const cv::Mat& m, bool is_float) {
      cv::Mat t = m;
      if (is_float) m.convertTo(t, m.channels() == 1 ? CV_8UC1 : CV_8UC3, 255.0);
      if (t.channels() == 1) cv::cvtColor(t, t, cv::COLOR_GRAY2BGR);
      cv::resize(t, t, tile, 0, 0, cv::INTER_AREA);
      tiles.push_back(t);
    };
    add(portrait.image_unmatted, false);
    add(morphable::DrawFitOverlay(portrait.image_unmatted, model, fit, portrait.landmarks), false);
    add(exp_src.image, true);
    add(exp_edit.image, true);
    add(neu.image, true);
    add(neu.mask, true);
    cv::Mat strip;
    cv::hconcat(tiles, strip);
    SaveImage(dir / "summary.png", strip);
  }
  nlohmann::json j;
  j["input"] = o.input;
  j["alpha"] = fit.alpha;
  j["beta"] = fit.beta;
  j["beta_edited"] = edited;
  nlohmann::json e = nlohmann::json::object();
  for (const auto& [k, v] : o.edits) e[k] = v;
  j["expr"] = e;
  j["scale"] = fit.scale;
  j["camera_label"] = std::vector<float>(fit.camera.begin(), fit.camera.end());
  j["camera_label_convention"] = "row-major cam2world 4x4 (OpenCV camera axes, radius 2.7) + normalised intrinsics 3x3";
  j["crop_size"] = {crop.width, crop.height};
  j["mean_error_px"] = fit.mean_error_px;
  j["inter_ocular_px"] = fit.inter_ocular_px;
  j["mean_error_iod"] = fit.mean_error_iod;
  j["landmark_error_px"] = fit.landmark_error;
  j["crop_from_image"] = {portrait.crop_from_image(0, 0), portrait.crop_from_image(0, 1),
                          portrait.crop_from_image(0, 2), portrait.crop_from_image(1, 0),
                          portrait.crop_from_image(1, 1), portrait.crop_from_image(1, 2)};
  j["options"] = options::ToJson(o.fit);
  WriteBytesAtomically(dir / "fit.json", j.dump(2) + "\n");
  return fit;
}

}  // namespace

void PortraitFitOptions::Validate() const {
  AVATAR_CHECK_OPTION(!input.empty()) << "missing IMAGE: give the portrait to fit";
  AVATAR_CHECK_OPTION(!out_dir.empty()) << "--out-dir must not be empty";
  AVATAR_CHECK_OPTION(size >= 16 && size <= 4096) << "--size must be in 16..4096";
  AVATAR_CHECK_OPTION(supersample >= 1 && supersample <= 4) << "--supersample must be in 1..4";
  fit.Validate();
  texture.Validate();
}

std::vector<FaceFitOutcome> FitPortrait(const PortraitFitOptions& o, RunContext& ctx,
                                        const std::function<void(const FaceFitOutcome&)>& on_face) {
  o.Validate();
  const DataPaths paths = DataPaths::Resolve(o.data_dir);
  std::optional<morphable::MorphableModel> custom;
  if (!o.model.empty()) custom = morphable::MorphableModel::Load(o.model, morphable::LoadTopology(paths));
  const morphable::MorphableModel& model = custom ? *custom : morphable::LoadDefaultModel(paths);
  model.ExpressionFromControls(o.edits);  // validates the names before the slow part
  const cv::Mat bgr = LoadImageBgr(o.input);
  face::FaceAnalyzerOptions fa;
  fa.data_dir = o.data_dir;
  fa.embedding = false;
  std::vector<int> indices = {o.face_index};
  if (o.all_faces) {
    const face::FaceAnalyzer detector(fa);
    indices.clear();
    for (size_t k = 0; k < detector.Detect(bgr).size(); ++k) indices.push_back(static_cast<int>(k));
  }
  std::vector<FaceFitOutcome> outcomes;
  for (int index : indices) {
    ctx.ThrowIfCancelled();
    fa.face_index = index;
    const face::FaceAnalyzer analyzer(fa);
    FaceFitOutcome outcome;
    outcome.face_index = index;
    face::AlignedPortrait portrait;
    try {
      portrait = analyzer.AnalyzePortrait(bgr, ctx);
    } catch (const InvalidInput& e) {
      if (!o.all_faces) throw InvalidInput("photo '" + o.input + "': " + e.what());
      outcome.skipped = true;
      outcome.skip_reason = e.what();
    }
    if (!outcome.skipped) {
      const fs::path dir =
          o.all_faces ? fs::path(o.out_dir) / ("face_" + std::to_string(index)) : fs::path(o.out_dir);
      outcome.fit = FitOne(o, model, portrait, dir);
      outcome.dir = dir.string();
    }
    if (on_face) on_face(outcome);
    outcomes.push_back(std::move(outcome));
  }
  return outcomes;
}

}  // namespace avatar
