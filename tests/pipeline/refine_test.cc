// Per-portrait refinement of the cached planes (core/pipeline/refine.h) on a tiny random-weight
// session and a synthetic portrait: the source view gets closer, seeds repeat bit for bit,
// a cancel stops the step it lands in, refined avatars survive their file, extreme settings stay finite.
// With the bundled model, on a synthetic head whose turned views are known: the source view gains and
// the views at yaw +-20 do not get worse.

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <thread>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>
#include <torch/torch.h>

#include "common/cancel_on_report.h"
#include "common/temp_dir.h"
#include "core/io/data_paths.h"
#include "core/io/resources.h"
#include "core/morphable/morphable.h"
#include "core/pipeline/morphable_expression_source.h"
#include "core/pipeline/refine.h"
#include "core/pipeline/session.h"
#include "core/pipeline/session_access.h"
#include "core/pipeline/source_analysis.h"
#include "core/tools/synthetic_head.h"
#include "core/render/view_pose.h"
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

// Forty steps at lr 0.05 on the tiny random network: the refinement is deterministic (fixed
// render samples, seeded TV points), so the bars only need to cover float kernels. Measured
// 2026-12-04 (AMD EPYC, AVX-512) over AVATAR_THREADS 1 and 2 and the OpenBLAS core types Haswell
// (this CPU's default), Zen, SkylakeX, Sandybridge, Prescott, and Haswell with oneDNN and ATen
// limited to AVX2: source-view PSNR 9.349 -> 18.509 dB (gain 9.160) and the objective 0.5654 ->
// 0.1962 (0.347 of it) in every configuration, equal to the third decimal. The bars: a gain of
// 6 dB (the masked MSE falls 4x) and the objective at most half its start, each about 3 dB (or
// 0.15) short of the measurement.
TEST_F(Refine, SourceViewPsnrGrows) {
  RunContext ctx;
  const double before = SourceViewPsnr(*session_, avatar_, target_);
  const RefineResult r = RefineAvatar(*session_, avatar_, target_, FastOptions(40), ctx);
  const double after = SourceViewPsnr(*session_, r.avatar, target_);
  std::printf(
      "tiny random weights: source-view PSNR %.3f -> %.3f dB (gain %.3f) after %d steps (%.2f s), objective "
      "%.5f -> %.5f (ratio %.4f)\n",
      before, after, after - before, r.steps, r.seconds, r.loss_before, r.loss_after, r.loss_after / r.loss_before);
  EXPECT_EQ(r.steps, 40);
  EXPECT_EQ(r.stopped_by, "steps");
  EXPECT_NEAR(r.psnr_before, before, 1e-6);
  EXPECT_NEAR(r.psnr_after, after, 1e-4);
  EXPECT_GT(after, before + 6.0);
  EXPECT_LT(r.loss_after, 0.5 * r.loss_before);
  EXPECT_FALSE(SamePlanes(r.avatar, avatar_));
  // The input avatar is untouched and the refined one renders.
  EXPECT_EQ(SourceViewPsnr(*session_, avatar_, target_), before);
  const Frame f = session_->Animate(r.avatar, {}, ViewPose{30}, RenderMode::kStandard);
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

// A cancel from another thread (the studio's Cancel button) is prompt: the refinement ends with
// Cancelled inside the step it lands in, so at most the step in flight reports after the request.
// Judged by progress reports, not milliseconds (speed belongs in benchmarks). A
// refinement that ignored the cancel would run its million steps: the sink stops it after 20 more
// reports.
TEST_F(Refine, CancelFromAnotherThreadIsPrompt) {
  const RefineOptions o = FastOptions(1000000);
  for (const size_t trigger : {1u, 4u}) {  // after "preparing" and the first step, and after step 4
    const testing::CancelOutcome c = testing::RunAndCancelAtReport(
        [&](RunContext& ctx) { RefineAvatar(*session_, avatar_, target_, o, ctx); }, trigger, 20);
    SCOPED_TRACE(c.Describe());
    EXPECT_TRUE(c.requested);
    EXPECT_TRUE(c.cancelled);
    EXPECT_LE(c.ReportsAfterRequest(), 1u) << "the refinement went on after the cancel";
    EXPECT_EQ(c.LastStage(), "refine");
    EXPECT_NE(c.reports.back().message, "done");
    EXPECT_LT(c.seconds_after_request, testing::kCancelHangLimitSeconds) << "hang limit";
  }
}

// The bundled model (config cpu, the default, perceptual term included): its steps are long
// (several renders, forward and backward), so the cancel is checked inside them. The latency is
// counted in steps: the request comes right after the first step's report, and the second step
// must not complete (milliseconds are a benchmark's measure, not a test's).
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
  RefineOptions o;  // the defaults
  o.steps = 1000000;
  const RefineTarget target = Target(portrait);
  // Reports: "preparing", then one per step; the trigger is step 1's.
  const testing::CancelOutcome c = testing::RunAndCancelAtReport(
      [&](RunContext& ctx) { RefineAvatar(session, avatar, target, o, ctx); }, 1, 20);
  if (c.other_kind == "model_load")
    FAIL() << "MobileNetV2 (nsfwjs) weights not installed (run scripts/setup): " << c.other_error;
  SCOPED_TRACE(c.Describe());
  EXPECT_TRUE(c.requested);
  EXPECT_TRUE(c.cancelled);
  // The request comes a thread switch after step 1's report, early in step 2 (a third of a second
  // of renders here), which then stops at its next check instead of reporting. (A request that
  // came only with step 2's report counts as before it: RunAndCancelAtReport holds that report.)
  EXPECT_EQ(c.ReportsAfterRequest(), 0u) << "step 2 completed after the cancel: no check inside the step";
  EXPECT_EQ(c.LastStage(), "refine");
  EXPECT_LT(c.seconds_after_request, testing::kCancelHangLimitSeconds) << "hang limit";
}

// A budget in seconds alone (no step count) ends the run by itself: it stops because of the
// budget (not before it), after at least one step, and says so. The time is checked between steps,
// so the run overshoots by at most one step and the final evaluation; the progress sink's limit is
// a hang limit (a budget that is never checked would refine for ever), not a speed target.
TEST_F(Refine, SecondsBudgetEndsTheRun) {
  RefineOptions o = FastOptions(0);
  o.seconds = 0.5;
  const auto start = std::chrono::steady_clock::now();
  RunContext ctx([&](const Progress&) {
    if (std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() >
        o.seconds + testing::kCancelHangLimitSeconds)
      throw std::runtime_error("still refining long after the budget: it was not applied");
  });
  RefineResult r;
  ASSERT_NO_THROW(r = RefineAvatar(*session_, avatar_, target_, o, ctx));
  EXPECT_EQ(r.stopped_by, "seconds");
  EXPECT_GE(r.steps, 1);
  EXPECT_GE(r.seconds, o.seconds);
  EXPECT_DOUBLE_EQ(ctx.Last().fraction, 1.0);
  const nlohmann::json info = nlohmann::json::parse(r.avatar.RefinementInfo());
  EXPECT_EQ(info.at("stopped_by").get<std::string>(), "seconds");
  EXPECT_EQ(info.at("steps").get<int>(), r.steps);
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
    const Frame a = session_->Animate(r.avatar, Expression{{{"jawOpen", 0.4f}}}, view, RenderMode::kStandard);
    const Frame b = session_->Animate(loaded, Expression{{{"jawOpen", 0.4f}}}, view, RenderMode::kStandard);
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
  const Frame f = session_->Animate(r.avatar, {}, ViewPose{}, RenderMode::kStandard);
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
  const Frame reference = session_->Animate(avatar_, {}, ViewPose{20}, RenderMode::kStandard);
  RefineResult r;
  std::thread refiner([&] {
    RunContext ctx;
    r = RefineAvatar(*session_, avatar_, target_, FastOptions(30), ctx);
  });
  int frames = 0;
  for (; frames < 10; ++frames) {
    const Frame f = session_->Animate(avatar_, {}, ViewPose{20}, RenderMode::kStandard);
    EXPECT_EQ(cv::norm(f.bgr, reference.bgr, cv::NORM_INF), 0.0) << "frame " << frames;
  }
  refiner.join();
  EXPECT_EQ(r.steps, 30);
  const Frame after = session_->Animate(avatar_, {}, ViewPose{20}, RenderMode::kStandard);
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

// ---------------------------------------------------------------------------------------------
// The bundled model on a head whose turned views are known. A synthetic 2.5D head (core/pipeline/
// synthetic_head.h: what the data factory renders the bundled model's multi-view training pairs
// from) is built from a portrait of the morphable model's mean face seen by C_front; its render
// at C_s is that portrait, and its renders at yaw -20 and +20 are the ground truth of the turned
// views. The session reconstructs the portrait with the morphable expression source of the same
// fit, as the analysis path would.

// Smooth colours in [0,1]^2 (low frequencies only): a skin-toned face texture and darker hair.
cv::Vec3f SkinPattern(double u, double v) {
  return cv::Vec3f(static_cast<float>(0.45 + 0.15 * u), static_cast<float>(0.55 + 0.1 * v),
                   static_cast<float>(0.75 + 0.1 * std::sin(6.0 * u + 3.0 * v)));
}
cv::Vec3f HairPattern(double u, double v) {
  return cv::Vec3f(static_cast<float>(0.12 + 0.08 * std::sin(9.0 * v)), static_cast<float>(0.18 + 0.06 * u),
                   static_cast<float>(0.28 + 0.08 * std::cos(7.0 * u + 2.0 * v)));
}

struct KnownHead {
  SourceAnalysis analysis;  // the portrait (512, matted on black), C_s, the fit and its texture
  SyntheticHead head;       // built at 256 px
};

KnownHead MakeKnownHead() {
  const morphable::MorphableModel& model = morphable::LoadDefaultModel(DataPaths::Resolve());
  const int size = 512;
  const morphable::CameraLabel camera = morphable::FrontalLabel();
  KnownHead k;
  k.analysis.model = &model;
  k.analysis.morphable_fit = morphable::FitFromLabel(model.ZeroAlpha(), model.ZeroBeta(), 1.0f, camera, cv::Size(size, size));
  k.analysis.texture.uv_image = cv::Mat(128, 128, CV_32FC3);
  for (int y = 0; y < 128; ++y) {
    for (int x = 0; x < 128; ++x)
      k.analysis.texture.uv_image.at<cv::Vec3f>(y, x) = SkinPattern((x + 0.5) / 128, 1.0 - (y + 0.5) / 128);
  }
  morphable::RenderOptions ro;
  ro.supersample = 2;
  const morphable::RenderResult face = morphable::Render(model, model.ZeroAlpha(), model.ZeroBeta(), 1.0f,
                                                         k.analysis.texture, camera, cv::Size(size, size), ro);
  // Hair: an ellipse around the face's bounding box, and a neck down to the bottom border.
  cv::Mat hair(size, size, CV_8UC1, cv::Scalar(0));
  const cv::Rect box = cv::boundingRect(face.mask > 0.5f);
  cv::ellipse(hair, cv::Point(box.x + box.width / 2, box.y + box.height / 2 - box.height / 8),
              cv::Size(box.width * 7 / 10, box.height * 3 / 4), 0, 0, 360, cv::Scalar(255), cv::FILLED);
  cv::rectangle(hair, cv::Point(box.x + box.width / 4, box.y + box.height / 2),
                cv::Point(box.x + 3 * box.width / 4, size - 1), cv::Scalar(255), cv::FILLED);
  cv::Mat colour(size, size, CV_32FC3);
  for (int y = 0; y < size; ++y) {
    for (int x = 0; x < size; ++x) {
      const float f = face.mask.at<float>(y, x);
      colour.at<cv::Vec3f>(y, x) =
          f * face.image.at<cv::Vec3f>(y, x) + (1.0f - f) * HairPattern((x + 0.5) / size, (y + 0.5) / size);
    }
  }
  // Brows, eyes and lips drawn on the face (placed by its bounding box), so that the source view
  // has detail the refinement can fit; they make the eye/mouth mask, as the analysis would.
  const auto at = [&](double fx, double fy) {
    return cv::Point(box.x + static_cast<int>(fx * box.width), box.y + static_cast<int>(fy * box.height));
  };
  const auto axes = [&](double fx, double fy) {
    return cv::Size(static_cast<int>(fx * box.width), static_cast<int>(fy * box.height));
  };
  cv::Mat eye_mouth = cv::Mat::zeros(size, size, CV_8UC1);
  for (const double side : {0.3, 0.7}) {
    cv::ellipse(colour, at(side, 0.30), axes(0.1, 0.02), 0, 0, 360, cv::Scalar(0.1, 0.12, 0.2), cv::FILLED);
    cv::ellipse(eye_mouth, at(side, 0.30), axes(0.11, 0.03), 0, 0, 360, cv::Scalar(255), cv::FILLED);
    cv::ellipse(colour, at(side, 0.40), axes(0.09, 0.035), 0, 0, 360, cv::Scalar(0.92, 0.92, 0.92), cv::FILLED);
    cv::circle(colour, at(side, 0.40), box.width / 30, cv::Scalar(0.35, 0.25, 0.1), cv::FILLED);
    cv::ellipse(eye_mouth, at(side, 0.40), axes(0.1, 0.045), 0, 0, 360, cv::Scalar(255), cv::FILLED);
  }
  cv::ellipse(colour, at(0.5, 0.75), axes(0.15, 0.04), 0, 0, 360, cv::Scalar(0.3, 0.3, 0.7), cv::FILLED);
  cv::ellipse(eye_mouth, at(0.5, 0.75), axes(0.16, 0.05), 0, 0, 360, cv::Scalar(255), cv::FILLED);
  // The person matte (hair and face), and the portrait matted onto black.
  const cv::Mat person = (hair > 0) | (face.mask > 0.5f);
  cv::Mat matte, matte3, matted, bgr;
  person.convertTo(matte, CV_32FC1, 1.0 / 255.0);
  cv::cvtColor(matte, matte3, cv::COLOR_GRAY2BGR);
  cv::multiply(colour, matte3, matted);
  matted.convertTo(bgr, CV_8UC3, 255.0);
  k.analysis.portrait = PortraitFromAlignedImage(bgr);
  k.analysis.portrait.matte = matte;
  k.analysis.portrait.eye_mouth_mask = eye_mouth;
  k.analysis.fit.camera = camera;
  k.analysis.fit.expressions =
      std::make_shared<MorphableExpressionSource>(model, k.analysis.morphable_fit, k.analysis.texture);
  cv::Mat small_bgr, small_matte;
  cv::resize(bgr, small_bgr, cv::Size(256, 256), 0, 0, cv::INTER_AREA);
  cv::resize(matte, small_matte, cv::Size(256, 256), 0, 0, cv::INTER_AREA);
  k.head = BuildSyntheticHead(model, k.analysis.morphable_fit, small_bgr, small_matte, cv::Mat());
  return k;
}

// The head seen by `camera` at `size` px, on black (rendered at 128 px, area-downsampled).
cv::Mat KnownView(const SyntheticHead& head, const std::array<float, 25>& camera, int size) {
  const SyntheticView v = RenderSyntheticView(head, head.vertices, camera, cv::Size(128, 128), 2);
  cv::Mat alpha3, on_black, out;
  cv::cvtColor(v.alpha, alpha3, cv::COLOR_GRAY2BGR);
  cv::multiply(v.image, alpha3, on_black);
  cv::resize(on_black, out, cv::Size(size, size), 0, 0, cv::INTER_AREA);
  return out;
}

// PSNR (dB, peak 1) of an 8-bit frame against a float [0,1] image over the whole frame.
double FramePsnr(const cv::Mat& bgr8, const cv::Mat& truth) {
  cv::Mat f;
  bgr8.convertTo(f, CV_32FC3, 1.0 / 255.0);
  cv::Mat d = f - truth;
  const double mse = cv::mean(d.mul(d)).dot(cv::Scalar(1, 1, 1, 0)) / 3.0;
  return 10.0 * std::log10(1.0 / std::max(mse, 1e-20));
}

// Ten refinement steps with the default options (perceptual, neutral, TV and prior terms) bring
// the source view closer to the photo, and the turned views at yaw -20 and +20, which the
// refinement never sees, may not end further from the known head than the one-shot planes' renders
// by more than 0.5 dB (the stated margin of this non-regression check). Turned views: PSNR of the
// frame (standard mode, render size 32) against the head's render at the same camera, both on
// black. Measured 2026-12-04 (AMD EPYC, AVX-512) over AVATAR_THREADS 1 and 2 and the OpenBLAS
// core types Haswell (this CPU's default), Zen, SkylakeX, Sandybridge, Prescott, and Haswell with
// oneDNN and ATen limited to AVX2: source view 19.602 -> 21.486 dB, a gain of 1.884 dB in every
// configuration; yaw -20 20.548 -> 21.676-21.680 dB (+1.128 to +1.132), yaw +20 20.553 -> 21.721
// dB (+1.168). The gain bar, 1 dB (the masked MSE falls 1.26x), is 0.88 dB below the measurement;
// the turned views end 1.6 dB above their bar.
TEST(RefineBundled, GainsAtTheSourceViewAndKeepsTheTurnedViews) {
  ASSERT_TRUE(testing::kSyntheticSourceLoaderRegistered);
  const auto checkpoint = ResourcePath(kBundledModelFile);
  ASSERT_TRUE(std::filesystem::exists(checkpoint)) << "bundled model missing (part of the repository): " << checkpoint;
  SessionOptions so;
  so.checkpoint = checkpoint.string();
  Session session(so);
  const KnownHead k = MakeKnownHead();
  RunContext build;
  const Avatar avatar = session.ReconstructFromAnalysis(k.analysis.portrait, k.analysis.fit, build);
  // What RefineAvatar(session, avatar, analysis, ...) fits; the refinement runs with the default options.
  const RefineTarget target = RefineTargetFromAnalysis(k.analysis);
  RefineOptions o;
  o.steps = 10;
  RunContext ctx;
  RefineResult r;
  try {
    r = RefineAvatar(session, avatar, target, o, ctx);
  } catch (const ModelLoad& e) {
    FAIL() << "MobileNetV2 (nsfwjs) weights not installed (run scripts/setup): " << e.what();
  }
  EXPECT_EQ(r.steps, o.steps);
  // The avatar handed back is measured, not the refinement's own account of it.
  const double source_before = SourceViewPsnr(session, avatar, target);
  const double source_after = SourceViewPsnr(session, r.avatar, target);
  std::printf(
      "bundled model, %d steps (%.2f s): source-view PSNR %.3f -> %.3f dB (gain %.3f), objective %.5f -> %.5f\n",
      r.steps, r.seconds, source_before, source_after, source_after - source_before, r.loss_before, r.loss_after);
  EXPECT_GT(source_after, source_before + 1.0) << "refinement did not bring the source view closer";
  const int res = session.Info().render_size;
  for (const double yaw : {-20.0, 20.0}) {
    const std::array<float, 25> camera = render::CameraForView(ViewPose{yaw}, avatar.SourceCamera());
    const cv::Mat truth = KnownView(k.head, camera, res);
    const double before = FramePsnr(session.Animate(avatar, {}, camera, RenderMode::kStandard).bgr, truth);
    const double after = FramePsnr(session.Animate(r.avatar, {}, camera, RenderMode::kStandard).bgr, truth);
    std::printf("bundled model, yaw %+.0f: PSNR against the known head %.3f dB one-shot, %.3f dB refined (%+.3f)\n",
                yaw, before, after, after - before);
    EXPECT_GT(after, before - 0.5) << "refinement made the view at yaw " << yaw << " worse";
  }
}

}  // namespace
}  // namespace avatar
