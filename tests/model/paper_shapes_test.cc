// The published sizes: one forward of each branch at the paper config (inference mode).

#include <gtest/gtest.h>

#include "core/model/goha_model.h"
#include "core/render/camera.h"
#include "model_test_util.h"

namespace avatar {
namespace {

using testing::Shape;

TEST(PaperShapes, EncoderFeaturesAndAllTriplanes) {
  torch::manual_seed(30);
  const ModelConfig c = ModelConfig::Paper();
  GohaModel model(c);
  model->eval();
  torch::InferenceMode inference;
  const torch::Tensor image = torch::rand({1, 3, 512, 512}) * 2 - 1;
  EXPECT_EQ(Shape(model->canonical_encoder->forward(image)), (std::vector<int64_t>{1, 256, 128, 128}));
  const torch::Tensor tc = model->CanonicalPlanes(image);
  EXPECT_EQ(Shape(tc), (std::vector<int64_t>{1, 3, 32, 256, 256}));
  const torch::Tensor te = model->ExpressionPlanes(image);
  EXPECT_EQ(Shape(te), (std::vector<int64_t>{1, 3, 32, 256, 256}));
  const AppearanceOutput app = model->AppearancePlanes(image, torch::zeros({1, 1, 512, 512}),
                                                       torch::ones({1, 1, 512, 512}), tc, render::FrontalCameras(1));
  EXPECT_EQ(Shape(app.planes), (std::vector<int64_t>{1, 3, 32, 256, 256}));
  EXPECT_EQ(Shape(app.depth), (std::vector<int64_t>{1, 1, 128, 128}));
  EXPECT_EQ(Shape(app.points), (std::vector<int64_t>{1, 128 * 128, 3}));
  EXPECT_TRUE(torch::isfinite(app.planes).all().item<bool>());
}

TEST(PaperShapes, SuperResolutionTo512) {
  torch::manual_seed(31);
  const ModelConfig c = ModelConfig::Paper();
  SuperResolution sr(c);
  torch::InferenceMode inference;
  const torch::Tensor out = sr->forward(torch::rand({1, 3, 128, 128}) * 2 - 1);
  EXPECT_EQ(Shape(out), (std::vector<int64_t>{1, 3, 512, 512}));
  EXPECT_TRUE(torch::isfinite(out).all().item<bool>());
}

}  // namespace
}  // namespace avatar
