// The `fit` and `build-morphable` commands end to end (the real executable on packaged data).

#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "common/run_process.h"
#include "common/temp_dir.h"
#include "core/io/data_paths.h"
#include "core/morphable/morphable.h"

namespace avatar::morphable {
namespace {

namespace fs = std::filesystem;

avatar::testing::ProcessResult RunCli(const std::string& args) {
  return avatar::testing::RunProcess(std::string("'") + AVATAR_STUDIO_EXE + "' " + args, "AVATAR_THREADS=2");
}

std::string Sample(const char* name) {
  return DataPaths::Resolve().Require(std::string("samples/") + name, "sample photos").string();
}

TEST(FitCommand, WritesEveryOutputWithCameraLabelAndError) {
  avatar::testing::TempDir dir;
  const auto r = RunCli("fit '" + Sample("grace_hopper.jpg") + "' --expr jawOpen=0.8 --expr smile=0.3 --out-dir '" +
                        (dir / "out").string() + "' --size 128");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* f :
       {"overlay.png", "I_exp_source.png", "I_exp_edited.png", "I_neu.png", "M_neu.png", "fit.json", "summary.png"}) {
    EXPECT_TRUE(fs::exists(dir / "out" / f)) << f;
  }
  std::ifstream in(dir / "out" / "fit.json");
  const nlohmann::json j = nlohmann::json::parse(in);
  EXPECT_EQ(j["camera_label"].size(), 25u);
  EXPECT_NEAR(j["camera_label"][16].get<double>(), 4.2647, 1e-3);
  EXPECT_LE(j["mean_error_iod"].get<double>(), 0.02);
  EXPECT_NEAR(j["expr"]["jawOpen"].get<double>(), 0.8, 1e-6);
  EXPECT_NE(j["beta"], j["beta_edited"]);
  EXPECT_NE(r.out.find("reprojection error"), std::string::npos);
}

TEST(FitCommand, BadInputsFailClearly) {
  avatar::testing::TempDir dir;
  const auto unknown =
      RunCli("fit '" + Sample("grace_hopper.jpg") + "' --expr wink=1 --out-dir '" + dir.path().string() + "'");
  EXPECT_NE(unknown.exit_code, 0);
  EXPECT_NE(unknown.err.find("jawOpen"), std::string::npos) << unknown.err;  // lists the known controls
  const auto malformed =
      RunCli("fit '" + Sample("grace_hopper.jpg") + "' --expr jawOpen --out-dir '" + dir.path().string() + "'");
  EXPECT_EQ(malformed.exit_code, 2) << malformed.err;
  const auto missing = RunCli("fit '" + (dir / "nothing.jpg").string() + "' --out-dir '" + dir.path().string() + "'");
  EXPECT_EQ(missing.exit_code, 1);
  EXPECT_NE(missing.err.find("nothing.jpg"), std::string::npos) << missing.err;
  const auto usage = RunCli("fit");
  EXPECT_EQ(usage.exit_code, 2);
}

TEST(BuildMorphableCommand, SmallBuildWritesALoadableModelAndStrips) {
  avatar::testing::TempDir dir;
  const auto r =
      RunCli("build-morphable --max-frames 40 --frame-stride 2 --no-photos --expression-components 24 --out '" +
             (dir / "m" / "model.avmm").string() + "' --strips-dir '" + (dir / "strips").string() + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const MorphableModel m = MorphableModel::Load(dir / "m" / "model.avmm", LoadTopology(DataPaths::Resolve()));
  EXPECT_EQ(m.num_expression(), 24 + 2);
  EXPECT_TRUE(fs::exists(dir / "m" / "PROVENANCE.txt"));
  EXPECT_TRUE(fs::exists(dir / "m" / "model.avmm.json"));
  for (const auto& name : RequiredControlNames())
    EXPECT_TRUE(fs::exists(dir / "strips" / ("control_" + name + ".png"))) << name;
}

}  // namespace
}  // namespace avatar::morphable
