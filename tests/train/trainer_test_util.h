#pragma once
// Helpers shared by the trainer tests: a finite-difference gradient check, a synthetic tiny
// batch source (one fixed pair, varied by the cursor so that resuming must restore the cursor)
// and small utilities.

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include <unistd.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "common/gradient_check.h"
#include "core/model/goha_model.h"
#include "core/render/camera.h"
#include "core/train/losses.h"
#include "core/train/trainer.h"
#include "core/util/run_context.h"

namespace avatar::train {
namespace {

namespace fs = std::filesystem;

// Central differences of a scalar function against autograd, every element of `x` (double).
inline void ExpectGradMatches(const std::function<torch::Tensor(const torch::Tensor&)>& f, const torch::Tensor& x0,
                       const std::string& what, double h = 1e-6, double tol = 1e-6) {
  const test::GradientCheck check = test::CheckGradient(f, x0, h);
  EXPECT_LT(check.worst_error, tol) << what << ": finite differences disagree with autograd by " << check.worst_error;
  EXPECT_GT(check.analytic_abs_sum, 0.0) << what << ": all-zero gradient";
}

// ---------------------------------------------------------------------------------------------
// Synthetic data: one fixed pair (tiny sizes), varied by the cursor so that resuming must
// restore the data cursor too.

inline TrainSample MakeSample(const ModelConfig& c, int64_t variant) {
  const int64_t s = c.image_size;
  const torch::Tensor yy = torch::linspace(-1, 1, s).view({1, s, 1}).expand({1, s, s});
  const torch::Tensor xx = torch::linspace(-1, 1, s).view({1, 1, s}).expand({1, s, s});
  const torch::Tensor disk = ((xx * xx + yy * yy) < 0.45).to(torch::kFloat32);
  const double shift = 0.05 * static_cast<double>(variant % 3);
  TrainSample t;
  t.source_matte = disk;
  t.source = torch::cat({(xx * 0.5 + shift) * disk, (yy * 0.5) * disk, disk * 0.6 - 0.3}, 0) * disk + (disk - 1);
  t.source_eye_mouth = ((yy.abs() < 0.1) * (xx.abs() < 0.3)).to(torch::kFloat32);
  t.source_label = render::LabelsFromCameras(render::FrontalCameras(1))[0];
  render::ViewPose pose;  // The camera 12 degrees to the side and 4 above.
  pose.yaw = 12;
  pose.pitch = -4;
  t.target_label =
      render::LabelsFromCameras({render::OrbitCam2World(pose).unsqueeze(0), render::DefaultIntrinsics().unsqueeze(0)})[0];
  t.target_matte = disk;
  t.target = torch::cat({(0.4 - yy * 0.3 + shift) * disk, (0.2 + xx * 0.3) * disk, (-0.1 + 0 * xx) * disk}, 0) + (disk - 1);
  t.expression_image = torch::cat({disk * 0.5, -disk * 0.2, xx * 0.3}, 0);
  t.neutral_image = t.source.clone();
  t.neutral_mask = disk;
  t.target_expression = torch::zeros({8});
  return t;
}

class SyntheticSource : public BatchSource {
 public:
  SyntheticSource(ModelConfig c, int64_t batch, bool vary) : c_(std::move(c)), batch_(batch), vary_(vary) {}
  TrainBatch Next() override {
    std::vector<TrainSample> samples;
    for (int64_t i = 0; i < batch_; ++i) samples.push_back(MakeSample(c_, vary_ ? cursor_ + i : 0));
    TrainBatch b = Collate(samples);
    if (poison_at_ >= 0 && (cursor_ == poison_at_ || (poison_all_ && cursor_ > poison_at_))) b.source[0][0][3][3] = NAN;
    if (cancel_at_ >= 0 && cursor_ == cancel_at_ && ctx_ != nullptr) ctx_->RequestCancel();
    ++cursor_;
    return b;
  }
  nlohmann::json State() const override { return {{"cursor", cursor_}}; }
  void Restore(const nlohmann::json& state) override { cursor_ = state.at("cursor").get<int64_t>(); }

  int64_t poison_at_ = -1;
  bool poison_all_ = false;
  int64_t cancel_at_ = -1;
  RunContext* ctx_ = nullptr;
  int64_t cursor() const { return cursor_; }

 private:
  ModelConfig c_;
  int64_t batch_;
  bool vary_;
  int64_t cursor_ = 0;
};

const PerceptualFn kStandIn = [](const torch::Tensor& a, const torch::Tensor& b) { return PyramidL1Distance(a, b); };

inline TrainerOptions TestOptions() {
  TrainerOptions o;
  o.lr = 1e-3;
  o.expression_start = 3;
  o.appearance_start = 6;
  o.tv_points = 200;
  return o;
}

inline fs::path TempDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("avatar_trainer_test_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

inline std::vector<torch::Tensor> Weights(GohaModel& m) {
  std::vector<torch::Tensor> out;
  for (const auto& p : m->parameters()) out.push_back(p.detach().clone());
  return out;
}

}  // namespace
}  // namespace avatar::train
