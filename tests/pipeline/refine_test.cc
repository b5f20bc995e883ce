// Per-portrait refinement of the cached planes (core/pipeline/refine.h) on a tiny random-weight
// session and a synthetic portrait: the source view gets closer, seeds repeat bit for bit,
// cancellation is prompt, refined avatars survive their file, extreme settings stay finite.

#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <thread>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>
#include <torch/torch.h>

#include "common/temp_dir.h"
#include "core/io/resources.h"
#include "core/pipeline/refine.h"
#include "core/pipeline/session.h"
#include "core/pipeline/session_access.h"
#include "core/util/error.h"
#include "synthetic_expression_source.h"

namespace avatar {
namespace {

using avatar::testing::FrontalFit;
using avatar::testing::TempDir;

SessionOptions TinyOptions() { return testing::TinySessionOptions(3); }

// A portrait with structure the one-shot random network cannot reproduce.
face::AlignedPortrait Portrait() {
  cv::Mat img = cv::Mat::zeros(512, 512, CV_8UC3);
  cv::circle(img, cv::Point(256, 256), 180, cv::Scalar(90, 140, 210), cv::FILLED);
  cv::rectangle(img, cv::Rect(150, 170, 80, 60), cv::Scalar(240, 240, 240), cv::FILLED);
  cv::rectangle(img, cv::Rect(290, 170, 80, 60), cv::Scalar(20, 60, 20), cv::FILLED);
  cv::ellipse(img, cv::Point(256, 350), cv::Size(90, 30), 0, 0, 360, cv::Scalar(40, 40, 160), cv::FILLED);
  face::AlignedPortrait p = PortraitFromAlignedImage(img);
  p.matte = cv::Mat::zeros(512, 512, CV_32FC1);
  cv::circle(p.matte, cv::Point(256, 256), 200, cv::Scalar(1.0f), cv::FILLED);
  cv::Mat m3;
  cv::cvtColor(p.matte, m3, cv::COLOR_GRAY2BGR);
  cv::Mat f;
  img.convertTo(f, CV_32FC3);
  cv::multiply(f, m3, f);
  f.convertTo(p.image, CV_8UC3);
  return p;
}

RefineTarget Target(const face::AlignedPortrait& p) {
  RefineTarget t;
  t.image = p.image;
  t.matte = p.matte;
  // A neutral image: the portrait's face disk, as a morphable render would cover it.
  cv::Mat neu = p.image.clone();
  neu.convertTo(t.neutral_image, CV_32FC3, 1.0 / 255.0);
  t.neutral_mask = cv::Mat::zeros(512, 512, CV_32FC1);
  cv::circle(t.neutral_mask, cv::Point(256, 256), 170, cv::Scalar(1.0f), cv::FILLED);
  return t;
}

// No MobileNetV2 download needed: the perceptual term has its own test.
RefineOptions FastOptions(int steps) {
  RefineOptions o;
  o.steps = steps;
  o.lr = 0.05;
  o.perceptual_weight = 0.0;
  o.tv_points = 200;
  o.prior_weight = 0.01;
  return o;
}

bool SamePlanes(const Avatar& a, const Avatar& b) {
  return torch::equal(SessionAccess::Canonical(a), SessionAccess::Canonical(b)) &&
         torch::equal(SessionAccess::Appearance(a), SessionAccess::Appearance(b));
}

class Refine : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(testing::kSyntheticSourceLoaderRegistered);
    session_ = std::make_unique<Session>(TinyOptions());
    portrait_ = Portrait();
    RunContext ctx;
    avatar_ = session_->ReconstructFromAnalysis(portrait_, FrontalFit(), ctx);
    target_ = Target(portrait_);
  }
  std::unique_ptr<Session> session_;
  face::AlignedPortrait portrait_;
  Avatar avatar_;
  RefineTarget target_;
};

TEST_F(Refine, SourceViewPsnrGrows) {
  RunContext ctx;
  const double before = SourceViewPsnr(*session_, avatar_, target_);
  const RefineResult r = RefineAvatar(*session_, avatar_, target_, FastOptions(40), ctx);
  const double after = SourceViewPsnr(*session_, r.avatar, target_);
  std::printf("tiny random weights: source-view PSNR %.2f -> %.2f dB after %d steps (%.2f s)\n", before, after,
              r.steps, r.seconds);
  EXPECT_EQ(r.steps, 40);
  EXPECT_EQ(r.stopped_by, "steps");
  EXPECT_NEAR(r.psnr_before, before, 1e-6);
  EXPECT_NEAR(r.psnr_after, after, 1e-4);
  EXPECT_GT(after, before + 1.0);
  EXPECT_LT(r.loss_after, r.loss_before);
  EXPECT_FALSE(SamePlanes(r.avatar, avatar_));
  // The input avatar is untouched and the refined one renders.
  EXPECT_EQ(SourceViewPsnr(*session_, avatar_, target_), before);
  const Frame f = session_->Animate(r.avatar, {}, ViewPose{30}, Preset::kStandard);
  EXPECT_EQ(f.bgr.rows, session_->Info().render_size);
  const nlohmann::json info = nlohmann::json::parse(r.avatar.RefinementInfo());
  EXPECT_EQ(info.at("steps").get<int>(), 40);
  EXPECT_TRUE(avatar_.RefinementInfo().empty());
}

TEST_F(Refine, PerceptualTermRuns) {
  RefineOptions o = FastOptions(5);
  o.perceptual_weight = 1.0;
  RunContext ctx;
  RefineResult r;
  try {
    r = RefineAvatar(*session_, avatar_, target_, o, ctx);
  } catch (const ModelLoad& e) {
    FAIL() << "MobileNetV2 (nsfwjs) weights not installed (run scripts/setup): " << e.what();
  }
  EXPECT_EQ(r.steps, 5);
  EXPECT_LE(r.loss_after, r.loss_before);
  EXPECT_TRUE(std::isfinite(r.psnr_after));
}

TEST_F(Refine, DeterministicBySeed) {
  RefineOptions o = FastOptions(6);
  o.tv_weight = 1.0;  // the random term
  RunContext c1, c2, c3;
  const RefineResult a = RefineAvatar(*session_, avatar_, target_, o, c1);
  const RefineResult b = RefineAvatar(*session_, avatar_, target_, o, c2);
  EXPECT_TRUE(SamePlanes(a.avatar, b.avatar));
  o.seed = 7;
  const RefineResult c = RefineAvatar(*session_, avatar_, target_, o, c3);
  EXPECT_FALSE(SamePlanes(a.avatar, c.avatar));
}

TEST_F(Refine, CancelFromAnotherThreadIsPrompt) {
  RefineOptions o = FastOptions(1000000);
  RunContext ctx;
  std::atomic<int> reports{0};
  std::chrono::steady_clock::time_point cancelled_at;
  std::thread canceller([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(400));
    cancelled_at = std::chrono::steady_clock::now();
    ctx.RequestCancel();
  });
  bool threw = false;
  try {
    RefineAvatar(*session_, avatar_, target_, o, ctx);
  } catch (const Cancelled&) {
    threw = true;
  }
  const auto stopped = std::chrono::steady_clock::now();
  canceller.join();
  const double ms = std::chrono::duration<double, std::milli>(stopped - cancelled_at).count();
  std::printf("refinement stopped %.1f ms after the cancel request (last progress: %s)\n", ms,
              ctx.Last().message.c_str());
  EXPECT_TRUE(threw);
  EXPECT_EQ(ctx.Last().stage, "refine");
  EXPECT_LT(ms, 1000.0);
}

// The bundled model (config cpu, the default): cancellation inside its longer steps.
TEST(RefineBundled, CancelLatencyOfTheDefaultModel) {
  ASSERT_TRUE(testing::kSyntheticSourceLoaderRegistered);
  const auto checkpoint = ResourcePath(kBundledModelFile);
  if (!std::filesystem::exists(checkpoint)) FAIL() << "bundled model not found (it is part of the repository): " << checkpoint;
  SessionOptions so;
  so.checkpoint = checkpoint.string();
  Session session(so);
  const face::AlignedPortrait portrait = Portrait();
  RunContext build;
  const Avatar avatar = session.ReconstructFromAnalysis(portrait, FrontalFit(), build);
  RefineOptions o;  // the defaults, perceptual term included
  o.steps = 1000000;
  RunContext ctx;
  std::chrono::steady_clock::time_point cancelled_at;
  std::thread canceller([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(1500));
    cancelled_at = std::chrono::steady_clock::now();
    ctx.RequestCancel();
  });
  bool threw = false;
  try {
    RefineAvatar(session, avatar, Target(portrait), o, ctx);
  } catch (const Cancelled&) {
    threw = true;
  } catch (const ModelLoad& e) {
    canceller.join();
    FAIL() << "MobileNetV2 (nsfwjs) weights not installed (run scripts/setup): " << e.what();
  }
  const auto stopped = std::chrono::steady_clock::now();
  canceller.join();
  const double ms = std::chrono::duration<double, std::milli>(stopped - cancelled_at).count();
  std::printf("default model: refinement stopped %.1f ms after the cancel request (%s)\n", ms,
              ctx.Last().message.c_str());
  EXPECT_TRUE(threw);
  EXPECT_LT(ms, 1000.0);
}

TEST_F(Refine, SecondsBudgetEndsTheRun) {
  RefineOptions o = FastOptions(0);
  o.seconds = 0.5;
  RunContext ctx;
  const RefineResult r = RefineAvatar(*session_, avatar_, target_, o, ctx);
  EXPECT_EQ(r.stopped_by, "seconds");
  EXPECT_GE(r.steps, 1);
  EXPECT_LT(r.seconds, 5.0);
  EXPECT_DOUBLE_EQ(ctx.Last().fraction, 1.0);
}

TEST_F(Refine, RefinedAvatarFileRoundTripIsExact) {
  RunContext ctx;
  const RefineResult r = RefineAvatar(*session_, avatar_, target_, FastOptions(5), ctx);
  TempDir dir;
  const auto path = dir.path() / "refined.avatar";
  session_->SaveAvatar(r.avatar, path);
  const Avatar loaded = session_->LoadAvatar(path);
  EXPECT_TRUE(SamePlanes(loaded, r.avatar));
  EXPECT_EQ(loaded.RefinementInfo(), r.avatar.RefinementInfo());
  for (const ViewPose& view : {ViewPose{}, ViewPose{30, -5}}) {
    const Frame a = session_->Animate(r.avatar, Expression{{{"jawOpen", 0.4f}}}, view, Preset::kStandard);
    const Frame b = session_->Animate(loaded, Expression{{{"jawOpen", 0.4f}}}, view, Preset::kStandard);
    EXPECT_EQ(cv::norm(a.bgr, b.bgr, cv::NORM_INF), 0.0);
    EXPECT_EQ(cv::norm(a.opacity, b.opacity, cv::NORM_INF), 0.0);
  }
}

TEST_F(Refine, ExtremeSettingsStayFinite) {
  RefineOptions o = FastOptions(8);
  o.lr = 10.0;  // the largest accepted
  o.grad_clip = 0.0;
  o.l1_weight = 1e6;
  o.tv_weight = 1e6;
  o.prior_weight = 0.0;
  RunContext ctx;
  const RefineResult r = RefineAvatar(*session_, avatar_, target_, o, ctx);
  std::printf("extreme settings: %d steps, stopped by %s, PSNR %.2f -> %.2f\n", r.steps, r.stopped_by.c_str(),
              r.psnr_before, r.psnr_after);
  EXPECT_TRUE(torch::isfinite(SessionAccess::Canonical(r.avatar)).all().item<bool>());
  EXPECT_TRUE(torch::isfinite(SessionAccess::Appearance(r.avatar)).all().item<bool>());
  EXPECT_TRUE(std::isfinite(r.loss_after));
  EXPECT_LE(r.loss_after, r.loss_before);  // the best evaluated planes are kept
  const Frame f = session_->Animate(r.avatar, {}, ViewPose{}, Preset::kStandard);
  EXPECT_TRUE(cv::checkRange(f.opacity) && cv::checkRange(f.depth));

  RefineOptions bad = FastOptions(1);
  bad.lr = 1e9;
  EXPECT_THROW(bad.Validate(), InvalidOptions);
  bad = FastOptions(1);
  bad.l1_weight = std::nan("");
  EXPECT_THROW(bad.Validate(), InvalidOptions);
  bad = FastOptions(1);
  bad.l1_weight = 0;
  EXPECT_THROW(bad.Validate(), InvalidOptions);
}

TEST_F(Refine, RejectsForeignAndEmptyAvatars) {
  RunContext ctx;
  EXPECT_THROW(RefineAvatar(*session_, Avatar{}, target_, FastOptions(1), ctx), InvalidInput);
  SessionOptions other = TinyOptions();
  other.seed = 4;
  Session foreign(other);
  EXPECT_THROW(RefineAvatar(foreign, avatar_, target_, FastOptions(1), ctx), InvalidInput);
  RefineTarget empty;
  EXPECT_THROW(RefineAvatar(*session_, avatar_, empty, FastOptions(1), ctx), InvalidInput);
}

TEST_F(Refine, LeavesTheSharedNetworkUntouchedWhileOthersAnimate) {
  const Frame reference = session_->Animate(avatar_, {}, ViewPose{20}, Preset::kStandard);
  RefineResult r;
  std::thread refiner([&] {
    RunContext ctx;
    r = RefineAvatar(*session_, avatar_, target_, FastOptions(30), ctx);
  });
  int frames = 0;
  for (; frames < 10; ++frames) {
    const Frame f = session_->Animate(avatar_, {}, ViewPose{20}, Preset::kStandard);
    EXPECT_EQ(cv::norm(f.bgr, reference.bgr, cv::NORM_INF), 0.0) << "frame " << frames;
  }
  refiner.join();
  EXPECT_EQ(r.steps, 30);
  const Frame after = session_->Animate(avatar_, {}, ViewPose{20}, Preset::kStandard);
  EXPECT_EQ(cv::norm(after.bgr, reference.bgr, cv::NORM_INF), 0.0);
  for (const auto& p : SessionAccess::Model(*session_)->parameters()) EXPECT_FALSE(p.grad().defined());
}

TEST_F(Refine, NoStepsKeepsThePlanes) {
  RefineOptions o = FastOptions(0);
  EXPECT_FALSE(o.Enabled());
  RunContext ctx;
  const RefineResult r = RefineAvatar(*session_, avatar_, target_, o, ctx);
  EXPECT_EQ(r.steps, 0);
  EXPECT_TRUE(SamePlanes(r.avatar, avatar_));
  EXPECT_DOUBLE_EQ(r.psnr_before, r.psnr_after);
}

}  // namespace
}  // namespace avatar
