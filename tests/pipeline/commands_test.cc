// The model commands of the avatar-studio executable: inspect reports the published shapes;
// without an installed model, commands say so clearly.

#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "common/run_process.h"
#include "common/temp_dir.h"
#include "core/io/image_io.h"
#include "core/pipeline/session.h"
#include "synthetic_expression_source.h"

namespace avatar {
namespace {

using avatar::testing::RunProcess;
using avatar::testing::TempDir;

const std::string kExe = std::string(AVATAR_BINARY_DIR) + "/app/avatar-studio";

bool Contains(const std::string& text, const std::string& what) { return text.find(what) != std::string::npos; }

TEST(Commands, InspectPaperReportsThePublishedShapes) {
  const auto r = RunProcess(kExe + " inspect --config paper");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* expected :
       {"I_s [1,3,512,512] | F_c [1,256,128,128]", "T_c [1,3,32,256,256]", "T_p [1,3,32,256,256]",
        "T_e [1,3,32,256,256]", "F [1,256,128,128]", "D_s [1,1,128,128]", "| [1,3,128,128] | [1,3,512,512] |",
        "(48+48 samples/ray)", "Total generator parameters", "| E_c/stage0 |", "| SR/stylegan_decoder |"}) {
    EXPECT_TRUE(Contains(r.out, expected)) << "missing '" << expected << "' in:\n" << r.out;
  }
}

TEST(Commands, InspectLiteAndBadConfig) {
  const auto lite = RunProcess(kExe + " inspect --config lite");
  ASSERT_EQ(lite.exit_code, 0) << lite.err;
  EXPECT_TRUE(Contains(lite.out, "T_c [1,3,32,128,128]")) << lite.out;
  EXPECT_TRUE(Contains(lite.out, "[1,3,256,256]")) << lite.out;
  const auto bad = RunProcess(kExe + " inspect --config enormous");
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_TRUE(Contains(bad.err, "enormous")) << bad.err;
}

TEST(Commands, RenderWithAnotherOrNoModelSaysSo) {
  TempDir dir;
  // A real avatar file (tiny random network) so that only the model is wrong.
  SessionOptions so;
  so.random_weights = true;
  so.config = "tiny";
  Session session(so);
  SourceFit fit;
  fit.camera = testing::FrontalCameraLabel();
  RunContext ctx;
  const Avatar avatar = session.ReconstructFromAnalysis(
      PortraitFromAlignedImage(cv::Mat(64, 64, CV_8UC3, cv::Scalar(90, 120, 160))), fit, ctx);
  session.SaveAvatar(avatar, dir / "a.avatar");
  const std::string render = kExe + " render '" + (dir / "a.avatar").string() + "' -o '" + (dir / "o.png").string() +
                             "' --data-dir '" + dir.path().string() + "'";
  // The bundled model loads, but the avatar belongs to other weights.
  const auto other = RunProcess(render);
  EXPECT_EQ(other.exit_code, 1);
  EXPECT_TRUE(Contains(other.err, "random:tiny:0")) << other.err;
  EXPECT_TRUE(Contains(other.err, "reconstruct the portrait again")) << other.err;
  // No model anywhere (a resource folder without the bundled model, nothing installed).
  TempDir empty;
  const auto none = RunProcess(render, "AVATAR_RESOURCE_DIR='" + empty.path().string() + "'");
  EXPECT_EQ(none.exit_code, 1);
  EXPECT_TRUE(Contains(none.err, "No GOHA model found")) << none.err;
  EXPECT_TRUE(Contains(none.err, "--checkpoint")) << none.err;
  EXPECT_FALSE(std::filesystem::exists(dir / "o.png"));
}

TEST(Commands, RenderRejectsMalformedExpressionsAndDamagedFiles) {
  TempDir dir;
  const auto bad_expr = RunProcess(kExe + " render x.avatar --random-weights --expr jawOpen");
  EXPECT_EQ(bad_expr.exit_code, 2) << bad_expr.err;
  EXPECT_TRUE(Contains(bad_expr.err, "name=value")) << bad_expr.err;
  {
    std::ofstream junk(dir / "junk.avatar");
    junk << "not an avatar";
  }
  const auto junk = RunProcess(kExe + " render '" + (dir / "junk.avatar").string() + "' --random-weights -o '" +
                               (dir / "o.png").string() + "'");
  EXPECT_EQ(junk.exit_code, 1);
  EXPECT_TRUE(Contains(junk.err, "junk.avatar")) << junk.err;
  EXPECT_FALSE(std::filesystem::exists(dir / "o.png"));
}

}  // namespace
}  // namespace avatar
