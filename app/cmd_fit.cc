// `avatar-studio fit IMAGE [--expr name=value ...] --out-dir DIR`: fits the morphable face model
// to the portrait's aligned 512 crop and writes the overlay, I_exp (source and edited
// expression at the frontal camera), I_neu / M_neu (neutral at the source camera) and a JSON
// with coefficients, camera label and fit error.

#include <algorithm>
#include <filesystem>
#include <functional>
#include <iomanip>
#include <iostream>
#include <optional>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "app/cli_util.h"
#include "app/cmd_bench.h"
#include "app/commands.h"
#include "core/face/face_analyzer.h"
#include "core/io/atomic_file.h"
#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/morphable/morphable.h"
#include "core/util/error.h"
#include "core/util/threads.h"
#include "core/util/timer.h"

namespace avatar::app {
namespace {

namespace fs = std::filesystem;

struct FitCommandOptions {
  // Portrait image.
  std::string input;
  // Output folder (created).
  std::string out_dir = "fit-out";
  // Expression edits "name=value" (repeatable), added to the fitted expression for I_exp_edited.
  std::vector<std::string> expr;
  // Side of the rendered images in pixels.
  int size = 512;
  // Supersampling of the renders.
  int supersample = 2;
  // Which face: -1 = main face, k = k-th detected face.
  int face_index = -1;
  // Fit every detected face of the image and print their errors (outputs per face in out_dir/face_k).
  bool all_faces = false;
  // Morphable model file ("" = the default model).
  std::string model;
  // Fitting.
  morphable::FitOptions fit;
  // Texture sampling.
  morphable::TextureOptions texture;
  // Threads, data folder, verbosity.
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("out_dir", out_dir, "Output folder", 'o');
    v("expr", expr, "Expression edit name=value (repeatable), e.g. --expr jawOpen=0.8");
    v("size", size, "Side of the rendered images in pixels");
    v("supersample", supersample, "Supersampling factor of the renders");
    v("face_index", face_index, "Face to fit: -1 = main face, k = k-th detected face");
    v("all_faces", all_faces, "Fit every detected face and print a table of reprojection errors");
    v("model", model, "Morphable model file (default: the bundled model)");
    fit.Visit(v);
    texture.Visit(v);
    common.Visit(v);
  }
  void Validate() const {
    AVATAR_CHECK_OPTION(!input.empty()) << "missing IMAGE: give the portrait to fit";
    AVATAR_CHECK_OPTION(!out_dir.empty()) << "--out-dir must not be empty";
    AVATAR_CHECK_OPTION(size >= 16 && size <= 4096) << "--size must be in 16..4096";
    AVATAR_CHECK_OPTION(supersample >= 1 && supersample <= 4) << "--supersample must be in 1..4";
    fit.Validate();
    texture.Validate();
    common.Validate();
  }
};

void SaveFloatImage(const fs::path& path, const cv::Mat& img) {
  cv::Mat out;
  img.convertTo(out, img.channels() == 1 ? CV_8UC1 : CV_8UC3, 255.0);
  SaveImage(path, out);
}

struct FaceOutcome {
  morphable::FitResult fit;
};

FaceOutcome FitOne(const FitCommandOptions& o, const morphable::MorphableModel& model,
                   const face::AlignedPortrait& portrait, const std::map<std::string, float>& edits,
                   const fs::path& dir) {
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
  const morphable::Beta delta = model.ExpressionFromControls(edits);
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
  for (const auto& [k, v] : edits) e[k] = v;
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
  return {fit};
}

int RunFitImpl(const FitCommandOptions& o, RunContext& ctx) {
  o.Validate();
  const auto edits = ParseControlFlags(o.expr);
  const DataPaths paths = DataPaths::Resolve(o.common.data_dir);
  std::optional<morphable::MorphableModel> custom;
  if (!o.model.empty()) custom = morphable::MorphableModel::Load(o.model, morphable::LoadTopology(paths));
  const morphable::MorphableModel& model = custom ? *custom : morphable::LoadDefaultModel(paths);
  model.ExpressionFromControls(edits);  // validates the names before the slow part
  const cv::Mat bgr = LoadImageBgr(o.input);
  face::FaceAnalyzerOptions fa;
  fa.data_dir = o.common.data_dir;
  fa.embedding = false;
  std::vector<int> indices = {o.face_index};
  if (o.all_faces) {
    const face::FaceAnalyzer detector(fa);
    indices.clear();
    for (size_t k = 0; k < detector.Detect(bgr).size(); ++k) indices.push_back(static_cast<int>(k));
  }
  std::cout << std::fixed << std::setprecision(2);
  for (int index : indices) {
    fa.face_index = index;
    const face::FaceAnalyzer analyzer(fa);
    face::AlignedPortrait portrait;
    try {
      portrait = analyzer.AnalyzePortrait(bgr, ctx);
    } catch (const InvalidInput& e) {
      if (!o.all_faces) throw InvalidInput("photo '" + o.input + "': " + e.what());
      std::cout << "face " << index << ": skipped (" << e.what() << ")\n";
      continue;
    }
    const fs::path dir = o.all_faces ? fs::path(o.out_dir) / ("face_" + std::to_string(index)) : fs::path(o.out_dir);
    const FaceOutcome r = FitOne(o, model, portrait, edits, dir);
    std::cout << (o.all_faces ? "face " + std::to_string(index) + ": " : std::string()) << "reprojection error "
              << r.fit.mean_error_px << " px = " << r.fit.mean_error_iod * 100 << "% of the inter-ocular distance ("
              << r.fit.inter_ocular_px << " px); wrote " << dir.string() << "\n";
  }
  return kExitOk;
}

int RunFit(const std::vector<std::string>& args) {
  return GuardedRun("fit", [&] {
    FitCommandOptions options;
    std::vector<std::string> positionals;
    if (!ParseCommand(options, args, "avatar-studio fit IMAGE [--expr name=value ...] --out-dir DIR",
                      "Fits the morphable face model to the portrait and writes overlay.png, I_exp_source.png,\n"
                      "I_exp_edited.png, I_neu.png, M_neu.png and fit.json (coefficients, camera label, error).\n"
                      "Expression controls: jawOpen smile frown pucker mouthWide browRaise browFrown blinkLeft\n"
                      "blinkRight eyesWide.",
                      &positionals)) {
      return kExitOk;
    }
    AVATAR_CHECK_OPTION(positionals.size() == 1) << "expected one IMAGE, got " << positionals.size() << " arguments";
    options.input = positionals[0];
    return RunFitImpl(options, ProcessContext());
  });
}

// `avatar-studio bench morphable`: fitting, texture and rendering speed on synthetic landmarks of
// the committed model (no face analysis), as milliseconds and as multiples of one fp32
// 1024^3 GEMM measured in the same run.
struct BenchMorphableOptions {
  // Timed repetitions (median reported).
  int repeats = 5;
  // Frames of the sequence fit.
  int frames = 50;
  // Threads, data folder, verbosity.
  CommonOptions common;

  template <typename V>
  void Visit(V&& v) {
    v("repeats", repeats, "Timed repetitions (median reported)");
    v("frames", frames, "Frames of the sequence fit");
    common.Visit(v);
  }
  void Validate() const {
    AVATAR_CHECK_OPTION(repeats >= 1 && repeats <= 100) << "--repeats must be in 1..100";
    AVATAR_CHECK_OPTION(frames >= 2 && frames <= 5000) << "--frames must be in 2..5000";
    common.Validate();
  }
};

double MedianMs(int repeats, const std::function<void()>& fn) {
  fn();  // warm-up
  std::vector<double> t;
  for (int i = 0; i < repeats; ++i) {
    Timer timer;
    fn();
    t.push_back(timer.Milliseconds());
  }
  std::sort(t.begin(), t.end());
  return t[t.size() / 2];
}

int RunBenchMorphableImpl(const BenchMorphableOptions& o, RunContext& ctx) {
  o.Validate();
  const DataPaths paths = DataPaths::Resolve(o.common.data_dir);
  const morphable::MorphableModel& m = morphable::LoadDefaultModel(paths);
  const double gflops = MeasureGemmGflops();
  const double gemm_ms = 2.0 * 1024 * 1024 * 1024 / (gflops * 1e9) * 1e3;
  // Synthetic landmarks: a random-ish face seen from a turned camera, facemesh depth convention.
  render::ViewPose pose;  // The camera 20 degrees to the side and 5 above.
  pose.yaw = 20;
  pose.pitch = -5;
  const morphable::CameraLabel cam = morphable::LabelFromTensor(
      render::LabelsFromCameras({render::OrbitCam2World(pose).unsqueeze(0), render::DefaultIntrinsics().unsqueeze(0)}));
  const cv::Size crop(512, 512);
  morphable::Beta beta = m.ExpressionFromControls({{"jawOpen", 0.5f}, {"smile", 0.3f}});
  const auto world = m.Vertices({}, beta);
  const morphable::PinholeCamera pc = morphable::PinholeCamera::FromLabel(cam);
  face::Landmarks lm;
  double zmean = 0;
  std::vector<cv::Vec3d> c;
  for (const auto& p : world) {
    c.push_back(pc.ToCamera(cv::Vec3d(p.x, p.y, p.z)));
    zmean += c.back()[2] / world.size();
  }
  for (const auto& q : c) {
    const cv::Point2d px = pc.ToPixel(q, crop);
    lm.points.emplace_back(px.x, px.y, render::kFocal * crop.width * (q[2] - zmean) / zmean);
  }
  morphable::FitResult fit;
  const double fit_ms = MedianMs(o.repeats, [&] { fit = morphable::Fit(m, lm, crop); });
  cv::Mat source(crop, CV_8UC3, cv::Scalar(90, 120, 160));
  morphable::Texture tex;
  const double tex_ms = MedianMs(o.repeats, [&] { tex = morphable::SampleTexture(m, fit, source); });
  morphable::RenderOptions ss1, ss2;
  ss2.supersample = 2;
  const double r1 = MedianMs(o.repeats, [&] { morphable::RenderNeutral(m, fit, tex, crop, ss1); });
  const double r2 = MedianMs(o.repeats, [&] { morphable::RenderNeutral(m, fit, tex, crop, ss2); });
  const double r256 = MedianMs(o.repeats, [&] {
    morphable::RenderExpressionImage(m, fit, tex, beta, {256, 256}, ss1);
  });
  std::vector<face::Landmarks> frames(o.frames, lm);
  const double seq_ms = MedianMs(1, [&] { morphable::FitSequence(m, frames, crop, morphable::FitOptions{}, ctx); });
  std::cout << "Morphable benchmark: " << ConfiguredThreads() << " threads, model with " << m.num_identity()
            << " identity + " << m.num_expression() << " expression components, median of " << o.repeats
            << " runs after a warm-up.\nBaseline: fp32 GEMM " << std::fixed << std::setprecision(1) << gflops
            << " GFLOP/s, one 1024^3 GEMM = " << std::setprecision(2) << gemm_ms << " ms\n\n"
            << "| stage | time (ms) | in 1024^3 GEMMs |\n|---|---|---|\n";
  auto row = [&](const char* name, double ms) {
    std::cout << "| " << name << " | " << std::setprecision(2) << ms << " | " << std::setprecision(1) << ms / gemm_ms
              << " |\n";
  };
  row("Fit (one 512 crop, 468 landmarks)", fit_ms);
  row("SampleTexture (256^2 UV)", tex_ms);
  row("Render 512^2 (I_neu)", r1);
  row("Render 512^2, 2x2 supersampling", r2);
  row("Render 256^2 (I_exp)", r256);
  row(("FitSequence per frame (" + std::to_string(o.frames) + " frames)").c_str(), seq_ms / o.frames);
  return kExitOk;
}

int RunBenchMorphable(const std::vector<std::string>& args) {
  return GuardedRun("bench morphable", [&] {
    BenchMorphableOptions options;
    std::vector<std::string> positionals;
    if (!ParseCommand(options, args, "avatar-studio bench morphable [options]",
                      "Speed of fitting, texture sampling and the CPU mesh renderer.", &positionals)) {
      return kExitOk;
    }
    AVATAR_CHECK_OPTION(positionals.empty()) << "bench morphable takes no positional arguments";
    return RunBenchMorphableImpl(options, ProcessContext());
  });
}

}  // namespace

AVATAR_REGISTER_BENCH_SUBJECT("morphable", "morphable model: fit, texture and mesh rendering speed", RunBenchMorphable);

AVATAR_REGISTER_COMMAND("fit", "fit the morphable face model to a portrait", RunFit);

}  // namespace avatar::app
