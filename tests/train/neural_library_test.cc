// test_train_neural links avatar_neural alone (every object of it, see tests/train/CMakeLists.txt),
// with no OpenCV and no Qt: the network, the renderer and the trainer build and run without them.
// A tiny stage-I trainer takes a few steps on a synthetic pair, exports its weights, and the
// checkpoint loads back to the same network with the same render.

#include <gtest/gtest.h>

#include "common/temp_dir.h"
#include "core/model/checkpoint.h"
#include "core/model/goha_model.h"
#include "core/render/camera.h"
#include "core/train/trainer.h"
#include "train/trainer_test_util.h"

namespace avatar::train {
namespace {

TEST(NeuralLibrary, TrainerStepsExportsAndReloadsWithoutOpenCvOrQt) {
  torch::manual_seed(41);
  const ModelConfig c = ModelConfig::Tiny();
  StageOneTrainer trainer(GohaModel(c), TestOptions(), kStandIn);
  SyntheticSource source(c, 2, true);
  for (int i = 0; i < 4; ++i) {
    const StepResult r = trainer.Step(source.Next());
    ASSERT_FALSE(r.skipped) << r.skip_reason;
    EXPECT_TRUE(std::isfinite(r.loss) && r.loss > 0.0) << "step " << i << ": loss " << r.loss;
    EXPECT_GT(r.grad_norm, 0.0) << "step " << i;
  }
  avatar::testing::TempDir dir;
  trainer.ExportWeights(dir / "model.ckpt", "synthetic pair (neural library test)");
  LoadedModel loaded = LoadModelCheckpoint(dir / "model.ckpt");
  EXPECT_EQ(loaded.info.step, 4);
  EXPECT_EQ(loaded.model->config(), c);
  const auto wa = Weights(trainer.model()), wb = Weights(loaded.model);
  ASSERT_EQ(wa.size(), wb.size());
  for (size_t i = 0; i < wa.size(); ++i) ASSERT_TRUE(torch::equal(wa[i], wb[i])) << "parameter " << i;

  torch::NoGradGuard no_grad;
  GohaModel trained = trainer.model(), reloaded = loaded.model;
  trained->eval();
  reloaded->eval();
  const TrainSample s = MakeSample(c, 0);
  const torch::Tensor source_image = s.source.unsqueeze(0);
  const render::Cameras cams = render::FrontalCameras(1);
  const torch::Tensor a = trained->Render(trained->CanonicalPlanes(source_image), cams).rgb;
  const torch::Tensor b = reloaded->Render(reloaded->CanonicalPlanes(source_image), cams).rgb;
  ASSERT_EQ(a.sizes(), (std::vector<int64_t>{1, 3, c.render_size, c.render_size}));
  EXPECT_TRUE(torch::isfinite(a).all().item<bool>());
  EXPECT_TRUE(torch::equal(a, b)) << "the reloaded network renders differently";
}

}  // namespace
}  // namespace avatar::train
