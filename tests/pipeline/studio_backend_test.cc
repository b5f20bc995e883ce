// CreateFrameSource, the one place that decides what renders a portrait: the bundled neural
// model by default, the morphable preview when chosen or when no model loads (with the reason),
// and an error, never a silent preview, for a checkpoint the user named. Real face analysis of
// the packaged sample portrait; a synthetic morphable model so that nothing depends on the
// committed one.

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <string>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "common/temp_dir.h"
#include "core/face/face_analyzer.h"
#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/io/resources.h"
#include "core/model/fusion_net.h"
#include "core/pipeline/detail_source.h"
#include "core/pipeline/studio_backend.h"
#include "core/util/error.h"
#include "morphable/morphable_test_util.h"

namespace avatar {
namespace {

using avatar::testing::TempDir;

class StudioBackend : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new TempDir();
    morphable::testing::SyntheticModel(morphable::testing::InstalledTopology(), 4, 6).Save(*dir_ / "model.avmm");
    // Restored after the suite: later suites of this process use the installed model.
    const char* previous = std::getenv("AVATAR_MORPHABLE_MODEL");
    previous_model_ = previous != nullptr ? new std::string(previous) : nullptr;
    ASSERT_EQ(setenv("AVATAR_MORPHABLE_MODEL", (*dir_ / "model.avmm").c_str(), 1), 0);
    portrait_ = new cv::Mat(LoadImageBgr(
        DataPaths::Resolve().Require(DataPaths::kDefaultPortrait, "the sample portrait (run scripts/setup)")));
  }
  static void TearDownTestSuite() {
    if (previous_model_ != nullptr) {
      setenv("AVATAR_MORPHABLE_MODEL", previous_model_->c_str(), 1);
    } else {
      unsetenv("AVATAR_MORPHABLE_MODEL");
    }
    delete previous_model_;
    previous_model_ = nullptr;
    delete portrait_;
    delete dir_;
  }
  static RenderedFrame Render(const FrameSource& source, double yaw) {
    FrameRequest r;
    r.width = r.height = 96;
    r.view.yaw = yaw;
    RunContext ctx;
    return source.Render(r, ctx);
  }
  static TempDir* dir_;
  static cv::Mat* portrait_;
  static std::string* previous_model_;
};
std::string* StudioBackend::previous_model_ = nullptr;
TempDir* StudioBackend::dir_ = nullptr;
cv::Mat* StudioBackend::portrait_ = nullptr;

TEST_F(StudioBackend, DefaultIsTheBundledNeuralModelAndItsFramesAreReal) {
  RunContext ctx;
  const auto source = CreateFrameSource(*portrait_, BackendOptions{}, ctx);
  EXPECT_EQ(source->Label().rfind("Neural avatar: bundled neural model ckpt:", 0), 0u) << source->Label();
  EXPECT_TRUE(source->SupportsPose());
  EXPECT_FALSE(source->Overlay().landmarks.empty());  // the analysis overlay reaches the source panel
  const RenderedFrame front = Render(*source, 0);
  const RenderedFrame side = Render(*source, 30);
  ASSERT_EQ(front.bgr.size(), cv::Size(96, 96));
  ASSERT_EQ(front.alpha.type(), CV_8UC1);
  // Alpha comes from the volume opacity: the head is opaque in the middle, the corners are not.
  EXPECT_GT(front.alpha.at<uint8_t>(48, 48), 128);
  EXPECT_LT(front.alpha.at<uint8_t>(2, 2), 128);
  cv::Mat diff;
  cv::absdiff(front.bgr, side.bgr, diff);
  const cv::Scalar d = cv::mean(diff);
  EXPECT_GT(d[0] + d[1] + d[2], 3 * 1.0) << "turning the camera did not change the neural frame";
  EXPECT_NE(BackendStatement(BackendOptions{}).find("bundled neural avatar model"), std::string::npos);
}

// The photo's detail over the neural head, finished by the bundled fusion net, is the default;
// --detail geometric is the same without the net, --detail off shows the network alone, and
// CreatePortraitPaths builds every path from one analysis with the same labels.
TEST_F(StudioBackend, DetailPathIsTheDefaultAndOffShowsTheNetworkAlone) {
  RunContext ctx;
  const auto learned = CreateFrameSource(*portrait_, BackendOptions{}, ctx);
  BackendOptions geometric_options;
  geometric_options.detail = "geometric";
  const auto with_detail = CreateFrameSource(*portrait_, geometric_options, ctx);
  BackendOptions off;
  off.detail = "off";
  const auto plain = CreateFrameSource(*portrait_, off, ctx);
  EXPECT_EQ(with_detail->Label(), plain->Label() + DetailLabel("head"));
  const std::string bundled = ResourcePath(kBundledFusionFile).string();
  FusionNetInfo bundled_info;
  LoadFusionNet(bundled, &bundled_info);
  EXPECT_EQ(FusionWeightsOf(BackendOptions{}), bundled);
  EXPECT_EQ(learned->Label(), with_detail->Label() + ", finished by the fusion net (step " +
                                  std::to_string(bundled_info.step) + ", fusion:" + bundled_info.fingerprint + ")");
  EXPECT_TRUE(learned->Warnings() == with_detail->Warnings());
  {
    // The finish is the net's: finite, and not the composite at a turned view.
    const RenderedFrame l = Render(*learned, 25), g = Render(*with_detail, 25);
    EXPECT_TRUE(cv::checkRange(l.bgr) && cv::checkRange(l.alpha));
    EXPECT_GT(cv::norm(l.bgr, g.bgr, cv::NORM_L1), 0.0) << "the fusion net changed nothing";
    EXPECT_EQ(cv::norm(l.alpha, g.alpha, cv::NORM_INF), 0.0);
  }
  // Which weights finish the frames: --fusion when named; none with geometric, face or off
  // unless named; none with random weights (the net never saw their renders).
  BackendOptions named;
  named.fusion = "/somewhere/f.ckpt";
  EXPECT_EQ(FusionWeightsOf(named), "/somewhere/f.ckpt");
  named.detail = "face";
  EXPECT_EQ(FusionWeightsOf(named), "/somewhere/f.ckpt");
  for (const char* mode : {"geometric", "face", "off"}) {
    BackendOptions o;
    o.detail = mode;
    EXPECT_EQ(FusionWeightsOf(o), "") << mode;
  }
  BackendOptions random;
  random.random_weights = true;
  EXPECT_EQ(FusionWeightsOf(random), "");
  for (const char* mode : {"geometric", "off"}) {
    BackendOptions both;
    both.detail = mode;
    both.fusion = "f.ckpt";
    EXPECT_THROW(both.Validate(), InvalidOptions) << mode;
  }
  EXPECT_EQ(plain->Label().find(kDetailLabel), std::string::npos) << plain->Label();
  EXPECT_EQ(&Unwrapped(*plain), plain.get());
  EXPECT_NE(&Unwrapped(*with_detail), with_detail.get());
  // At the photo's own view the face shows the photo's pixels: the frames differ there.
  const RenderedFrame a = Render(*with_detail, 0), b = Render(*plain, 0);
  cv::Mat diff;
  cv::absdiff(a.bgr, b.bgr, diff);
  const cv::Scalar d = cv::mean(diff);
  EXPECT_GT(d[0] + d[1] + d[2], 3 * 1.0) << "the detail path changed nothing";
  EXPECT_TRUE(cv::checkRange(a.bgr) && cv::checkRange(a.alpha));

  const PortraitPaths paths = CreatePortraitPaths(*portrait_, BackendOptions{}, ctx);
  EXPECT_EQ(paths.network->Label(), plain->Label());
  EXPECT_EQ(paths.detail->Label(), with_detail->Label());
  ASSERT_NE(paths.learned, nullptr);
  EXPECT_EQ(paths.learned->Label(), learned->Label());
  EXPECT_EQ(paths.preview->Label().rfind("Preview: morphable model", 0), 0u) << paths.preview->Label();
  EXPECT_EQ(paths.detail->Wrapped(), paths.network);
  EXPECT_EQ(paths.face->Wrapped(), paths.network);
  EXPECT_EQ(paths.face->Label(), plain->Label() + DetailLabel("face"));
  EXPECT_EQ(paths.portrait.image.size(), cv::Size(512, 512));

  BackendOptions bad;
  bad.detail = "sharp";
  EXPECT_THROW(bad.Validate(), InvalidOptions);
}

TEST_F(StudioBackend, MorphablePreviewWhenChosenOrWhenNoModelLoads) {
  RunContext ctx;
  BackendOptions chosen;
  chosen.renderer = "morphable";
  const auto preview = CreateFrameSource(*portrait_, chosen, ctx);
  EXPECT_EQ(preview->Label(), "Preview: morphable model (chosen instead of the neural avatar)");
  EXPECT_EQ(Render(*preview, 0).bgr.size(), cv::Size(96, 96));
  // No bundled model (an install whose resource folder lacks it): the preview, with the reason.
  TempDir empty;
  ASSERT_EQ(setenv("AVATAR_RESOURCE_DIR", empty.path().c_str(), 1), 0);
  BackendOptions defaults;  // (the test data folder has no models/goha.ckpt installed)
  const auto fallback = CreateFrameSource(*portrait_, defaults, ctx);
  const std::string label = fallback->Label();
  unsetenv("AVATAR_RESOURCE_DIR");
  EXPECT_EQ(label.rfind("Preview: morphable model (neural model unavailable: No GOHA model found", 0), 0u) << label;
  // The bundled model without the bundled fusion net: the geometric composite, and a warning
  // that says so and where it looked.
  std::filesystem::create_directories(empty.path() / "models");
  std::filesystem::create_symlink(std::filesystem::absolute(ResourcePath(kBundledModelFile)),
                                  empty.path() / "models" / "goha-default.ckpt");
  ASSERT_EQ(setenv("AVATAR_RESOURCE_DIR", empty.path().c_str(), 1), 0);
  std::string note;
  const std::string weights = FusionWeightsOf(defaults, &note);
  const auto unfinished = CreateFrameSource(*portrait_, defaults, ctx);
  unsetenv("AVATAR_RESOURCE_DIR");
  EXPECT_EQ(weights, "");
  EXPECT_NE(note.find((empty.path() / "models" / "fusion-default.ckpt").string()), std::string::npos) << note;
  EXPECT_EQ(unfinished->Label().find("fusion"), std::string::npos) << unfinished->Label();
  EXPECT_NE(unfinished->Label().find(DetailLabel("head")), std::string::npos) << unfinished->Label();
  ASSERT_FALSE(unfinished->Warnings().empty());
  EXPECT_EQ(unfinished->Warnings().back(), note);
  BackendOptions bad;
  bad.renderer = "mesh";
  EXPECT_THROW(bad.Validate(), InvalidOptions);
}

// A portrait whose face is between min_face_px and sharp_face_px is reconstructed, and the
// analysis warning (soft result) reaches the frame source, whichever renderer shows it.
TEST_F(StudioBackend, SmallFaceWarningReachesTheFrameSource) {
  RunContext ctx;
  const face::FaceAnalyzerOptions defaults;
  const auto faces = face::SharedFaceAnalyzer(defaults).Detect(*portrait_);
  ASSERT_EQ(faces.size(), 1u);
  const double side = std::max(faces[0].box.width, faces[0].box.height);
  const double target = (defaults.min_face_px + defaults.sharp_face_px) / 2.0;
  cv::Mat small;
  cv::resize(*portrait_, small, cv::Size(), target / side, target / side, cv::INTER_AREA);
  cv::Mat canvas(300, 300, CV_8UC3, cv::Scalar::all(90));
  small.copyTo(canvas(cv::Rect(100, 100, small.cols, small.rows)));
  BackendOptions morphable;
  morphable.renderer = "morphable";
  for (const BackendOptions& o : {morphable, BackendOptions{}}) {
    const auto source = CreateFrameSource(canvas, o, ctx);
    ASSERT_EQ(source->Warnings().size(), 1u) << o.renderer;
    EXPECT_NE(source->Warnings()[0].find("soft"), std::string::npos) << source->Warnings()[0];
  }
  EXPECT_TRUE(CreateFrameSource(*portrait_, morphable, ctx)->Warnings().empty()) << "a large face needs no warning";
}

TEST_F(StudioBackend, NamedCheckpointMustLoad) {
  TempDir dir;
  RunContext ctx;
  BackendOptions o;
  o.checkpoint = (dir / "missing.ckpt").string();
  try {
    CreateFrameSource(*portrait_, o, ctx);
    ADD_FAILURE() << "a missing --checkpoint must be an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("missing.ckpt"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace avatar
