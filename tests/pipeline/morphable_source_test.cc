// The session's morphable I_exp source: renders, controls, serialisation into avatar files.
// Uses a synthetic morphable model on the installed topology (no committed model needed).

#include <gtest/gtest.h>

#include <cstdlib>
#include <random>

#include "common/temp_dir.h"
#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/model/model_config.h"
#include "core/morphable/morphable.h"
#include "core/pipeline/morphable_expression_source.h"
#include "core/pipeline/session.h"
#include "core/util/error.h"
#include "morphable/morphable_test_util.h"

namespace avatar {
namespace {

using avatar::testing::TempDir;

struct Fixture {
  morphable::MorphableModel model;
  morphable::FitResult fit;
};

Fixture MakeFit() {
  Fixture f{morphable::testing::SyntheticModel(morphable::testing::InstalledTopology(), 4, 6), {}};
  std::mt19937 rng(3);
  const auto world = f.model.Vertices(f.model.ZeroAlpha(), f.model.ZeroBeta());
  const face::Landmarks lm =
      morphable::testing::ProjectLandmarks(world, morphable::FrontalLabel(), cv::Size(512, 512), 0.0, rng);
  f.fit = morphable::Fit(f.model, lm, cv::Size(512, 512));
  return f;
}

TEST(MorphableSource, RendersNeutralAndControlledExpressions) {
  const Fixture f = MakeFit();
  const MorphableExpressionSource source(f.model, f.fit, morphable::UniformTexture());
  const cv::Mat neutral = source.Render({}, 64);
  ASSERT_EQ(neutral.type(), CV_8UC3);
  ASSERT_EQ(neutral.rows, 64);
  EXPECT_GT(cv::countNonZero(neutral.reshape(1)), 100);        // a face, not an empty image
  EXPECT_EQ(neutral.at<cv::Vec3b>(0, 0), cv::Vec3b(0, 0, 0));  // black background
  const cv::Mat open = source.Render({{{"jawOpen", 3.0f}}}, 64);
  EXPECT_GT(cv::norm(neutral, open, cv::NORM_L1), 0.0);
  EXPECT_EQ(source.ControlNames().size(), morphable::RequiredControlNames().size());
  EXPECT_THROW(source.Render({{{"notAControl", 1.0f}}}, 64), InvalidInput);
  EXPECT_EQ(source.Kind(), "morphable");
}

TEST(MorphableSource, SerialisesIntoAvatarFiles) {
  TempDir dir;
  const Fixture f = MakeFit();
  // The loader uses the default model: point it at this synthetic model.
  f.model.Save(dir / "model.avmm");
  ASSERT_EQ(setenv("AVATAR_MORPHABLE_MODEL", (dir / "model.avmm").c_str(), 1), 0);
  auto source = std::make_shared<MorphableExpressionSource>(f.model, f.fit, morphable::UniformTexture());
  const std::string bytes = source->Serialize();
  const auto back = MorphableExpressionSource::Load(bytes);
  const Expression smile{{{"smile", 1.5f}}};
  EXPECT_EQ(cv::norm(source->Render(smile, 48), back->Render(smile, 48), cv::NORM_INF), 0.0);
  EXPECT_THROW(MorphableExpressionSource::Load(bytes.substr(0, bytes.size() / 2)), ModelLoad);
  EXPECT_THROW(MorphableExpressionSource::Load("xy"), ModelLoad);

  // Through a session and an avatar file: identical frames after loading.
  SessionOptions so;
  so.random_weights = true;
  so.config = "tiny";
  Session session(so);
  SourceFit fit;
  fit.camera = f.fit.camera;
  fit.expressions = source;
  RunContext ctx;
  const Avatar avatar = session.ReconstructFromAnalysis(
      PortraitFromAlignedImage(cv::Mat(512, 512, CV_8UC3, cv::Scalar(60, 90, 140))), fit, ctx);
  session.SaveAvatar(avatar, dir / "a.avatar");
  const Avatar loaded = session.LoadAvatar(dir / "a.avatar");
  const Frame a = session.Animate(avatar, smile, ViewPose{10}, RenderMode::kStandard);
  const Frame b = session.Animate(loaded, smile, ViewPose{10}, RenderMode::kStandard);
  EXPECT_EQ(cv::norm(a.bgr, b.bgr, cv::NORM_INF), 0.0);
  EXPECT_EQ(loaded.ControlNames(), avatar.ControlNames());
}

}  // namespace
}  // namespace avatar

namespace avatar {
namespace {

TEST(SessionEndToEnd, ReconstructsAPhotoThroughFaceAnalysisAndFitting) {
  // Real face analysis on the packaged sample (scripts/setup installs it); the morphable model
  // is the synthetic one so the test does not depend on the committed model.
  TempDir dir;
  const Fixture f = MakeFit();
  f.model.Save(dir / "model.avmm");
  ASSERT_EQ(setenv("AVATAR_MORPHABLE_MODEL", (dir / "model.avmm").c_str(), 1), 0);
  const std::filesystem::path photo = DataPaths::Resolve().Require(DataPaths::kDefaultPortrait, "end-to-end test");
  SessionOptions so;
  so.random_weights = true;
  so.config = "tiny";
  Session session(so);
  std::vector<std::string> stages;
  RunContext ctx([&](const Progress& p) { stages.push_back(p.stage); });
  const Avatar avatar = session.Reconstruct(LoadImageBgr(photo), ctx);
  ASSERT_TRUE(avatar.valid());
  EXPECT_EQ(avatar.SourceImage().size(), cv::Size(512, 512));
  EXPECT_NE(std::find(stages.begin(), stages.end(), "fit morphable model"), stages.end());
  EXPECT_NE(std::find(stages.begin(), stages.end(), "reconstruct"), stages.end());
  // The fitted source camera is a proper camera at the published radius.
  const auto cam = avatar.SourceCamera();
  const double radius = std::sqrt(cam[3] * cam[3] + cam[7] * cam[7] + cam[11] * cam[11]);
  EXPECT_NEAR(radius, 2.7, 0.05);
  const Frame frame = session.Animate(avatar, {{{"jawOpen", 0.5f}}}, ViewPose{15}, RenderMode::kFinal);
  EXPECT_EQ(frame.bgr.rows, ModelConfig::Tiny().sr_size);
  // A photo without a face is refused with InvalidInput.
  EXPECT_THROW(session.Reconstruct(cv::Mat(300, 300, CV_8UC3, cv::Scalar(30, 200, 30)), ctx), InvalidInput);
}

}  // namespace
}  // namespace avatar
