// Session: reconstruct once, animate many frames; caching (by counters), render modes, avatar files,
// errors, cancellation and concurrent use. Tiny random-weight network, synthetic inputs.

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <thread>

#include <opencv2/imgproc.hpp>

#include "common/temp_dir.h"
#include "common/tiny_checkpoint.h"
#include "core/io/atomic_file.h"
#include "core/model/goha_model.h"
#include "core/pipeline/session.h"
#include "core/pipeline/session_access.h"
#include "core/util/error.h"
#include "synthetic_expression_source.h"

namespace avatar {
namespace {

using avatar::testing::FrontalFit;
using avatar::testing::SyntheticExpressionSource;
using avatar::testing::TempDir;

SessionOptions TinyOptions(int seed = 0) { return testing::TinySessionOptions(seed); }

cv::Mat SyntheticPortrait(int size = 512) {
  cv::Mat img = cv::Mat::zeros(size, size, CV_8UC3);
  cv::circle(img, cv::Point(size / 2, size / 2), size / 3, cv::Scalar(120, 150, 200), cv::FILLED);
  cv::circle(img, cv::Point(size * 2 / 5, size * 2 / 5), size / 20, cv::Scalar(40, 40, 40), cv::FILLED);
  cv::circle(img, cv::Point(size * 3 / 5, size * 2 / 5), size / 20, cv::Scalar(40, 40, 40), cv::FILLED);
  return img;
}

Avatar MakeAvatar(const Session& session, const SourceFit& fit = FrontalFit()) {
  RunContext ctx;
  face::AlignedPortrait portrait = PortraitFromAlignedImage(SyntheticPortrait());
  portrait.eye_mouth_mask = cv::Mat::zeros(512, 512, CV_8UC1);
  cv::rectangle(portrait.eye_mouth_mask, cv::Rect(180, 180, 150, 40), cv::Scalar(255), cv::FILLED);
  portrait.matte = cv::Mat::zeros(512, 512, CV_32FC1);
  cv::circle(portrait.matte, cv::Point(256, 256), 200, cv::Scalar(1.0f), cv::FILLED);
  return session.ReconstructFromAnalysis(portrait, fit, ctx);
}

bool SameMat(const cv::Mat& a, const cv::Mat& b) {
  return a.size() == b.size() && a.type() == b.type() && cv::norm(a, b, cv::NORM_INF) == 0.0;
}

TEST(Session, CachingRunsOnlyWhatChanged) {
  ASSERT_TRUE(testing::kSyntheticSourceLoaderRegistered);
  Session session(TinyOptions());
  const Avatar avatar = MakeAvatar(session);
  SessionCounters c = session.Counters();
  EXPECT_EQ(c.canonical_encoder, 1);
  EXPECT_EQ(c.appearance_encoder, 1);
  EXPECT_EQ(c.rasterizations, 1);
  EXPECT_EQ(c.expression_encoder, 0);
  EXPECT_EQ(c.renders, 1);  // the lifting depth render

  session.ResetCounters();
  session.Animate(avatar, {}, ViewPose{}, RenderMode::kPreview);
  c = session.Counters();
  EXPECT_EQ(c.expression_images, 1);
  EXPECT_EQ(c.expression_encoder, 1);
  EXPECT_EQ(c.renders, 1);

  // Camera-only changes: zero encoders.
  session.ResetCounters();
  for (double yaw : {-30.0, 0.0, 25.0, 60.0}) session.Animate(avatar, {}, ViewPose{yaw, -10.0}, RenderMode::kPreview);
  c = session.Counters();
  EXPECT_EQ(c.canonical_encoder + c.appearance_encoder + c.expression_encoder, 0);
  EXPECT_EQ(c.expression_images, 0);
  EXPECT_EQ(c.rasterizations, 0);
  EXPECT_EQ(c.renders, 4);
  EXPECT_EQ(c.super_resolutions, 0);

  // Expression change: only E_e (and the expression image).
  session.ResetCounters();
  session.Animate(avatar, {{{"jawOpen", 0.7f}}}, ViewPose{10.0}, RenderMode::kPreview);
  c = session.Counters();
  EXPECT_EQ(c.expression_encoder, 1);
  EXPECT_EQ(c.expression_images, 1);
  EXPECT_EQ(c.canonical_encoder + c.appearance_encoder + c.rasterizations, 0);

  // An explicit zero is the neutral expression (cache hit), SR only for the final mode.
  session.ResetCounters();
  session.Animate(avatar, {{{"jawOpen", 0.0f}}}, ViewPose{}, RenderMode::kStandard);
  session.Animate(avatar, {{{"jawOpen", 0.7f}}}, ViewPose{}, RenderMode::kFinal);
  c = session.Counters();
  EXPECT_EQ(c.expression_encoder, 0);
  EXPECT_EQ(c.super_resolutions, 1);
  EXPECT_EQ(c.renders, 2);
}

TEST(Session, FramesHaveTheRightSizesAndRanges) {
  Session session(TinyOptions());
  const Avatar avatar = MakeAvatar(session);
  const ModelConfig c = ModelConfig::Tiny();
  for (RenderMode mode : {RenderMode::kPreview, RenderMode::kStandard, RenderMode::kFinal}) {
    const Frame f = session.Animate(avatar, {{{"smile", 0.5f}}}, ViewPose{20, 10, -5}, mode);
    const int side = mode == RenderMode::kFinal ? c.sr_size : c.render_size;
    EXPECT_EQ(f.bgr.type(), CV_8UC3);
    EXPECT_EQ(f.bgr.rows, side);
    EXPECT_EQ(f.bgr.cols, side);
    EXPECT_EQ(f.opacity.size(), f.bgr.size());
    EXPECT_EQ(f.depth.size(), f.bgr.size());
    EXPECT_EQ(f.super_resolved, mode == RenderMode::kFinal);
    double lo, hi;
    cv::minMaxLoc(f.opacity, &lo, &hi);
    EXPECT_GE(lo, 0.0);
    EXPECT_LE(hi, 1.0 + 1e-6);
    cv::minMaxLoc(f.depth, &lo, &hi);
    EXPECT_GE(lo, 2.25 - 1e-4);
    EXPECT_LE(hi, 3.3 + 1e-4);
    EXPECT_TRUE(cv::checkRange(f.depth));
  }
}

TEST(Session, DeterministicAndExpressionSensitive) {
  Session session(TinyOptions());
  const Avatar avatar = MakeAvatar(session);
  const Frame a = session.Animate(avatar, {{{"jawOpen", 1.0f}}}, ViewPose{15}, RenderMode::kStandard);
  const Frame b = session.Animate(avatar, {{{"jawOpen", 1.0f}}}, ViewPose{15}, RenderMode::kStandard);
  EXPECT_TRUE(SameMat(a.bgr, b.bgr));
  EXPECT_TRUE(SameMat(a.depth, b.depth));
  // A fresh session (cache cold) gives the same frame.
  Session other(TinyOptions());
  const Avatar avatar2 = MakeAvatar(other);
  EXPECT_TRUE(SameMat(a.bgr, other.Animate(avatar2, {{{"jawOpen", 1.0f}}}, ViewPose{15}, RenderMode::kStandard).bgr));
  // Changing the expression changes the frame (T_e differs), even with random weights.
  const Frame n = session.Animate(avatar, {}, ViewPose{15}, RenderMode::kStandard);
  EXPECT_GT(cv::norm(a.opacity, n.opacity, cv::NORM_INF) + cv::norm(a.bgr, n.bgr, cv::NORM_INF), 0.0);
}

TEST(Session, AvatarFileRoundTripGivesIdenticalFrames) {
  TempDir dir;
  Session session(TinyOptions(3));
  const Avatar avatar = MakeAvatar(session);
  session.SaveAvatar(avatar, dir.path() / "a.avatar");
  const Avatar loaded = session.LoadAvatar(dir.path() / "a.avatar");
  ASSERT_TRUE(loaded.valid());
  EXPECT_EQ(loaded.SourceCamera(), avatar.SourceCamera());
  EXPECT_TRUE(SameMat(loaded.SourceImage(), avatar.SourceImage()));
  EXPECT_EQ(loaded.ControlNames(), avatar.ControlNames());
  const Frame a = session.Animate(avatar, {{{"smile", 0.3f}}}, ViewPose{-20, -5}, RenderMode::kFinal);
  const Frame b = session.Animate(loaded, {{{"smile", 0.3f}}}, ViewPose{-20, -5}, RenderMode::kFinal);
  EXPECT_TRUE(SameMat(a.bgr, b.bgr));
  EXPECT_TRUE(SameMat(a.opacity, b.opacity));
  // Saving the loaded avatar again reproduces the file byte for byte.
  session.SaveAvatar(loaded, dir.path() / "b.avatar");
  EXPECT_EQ(ReadFileBytes(dir.path() / "a.avatar"), ReadFileBytes(dir.path() / "b.avatar"));
}

TEST(Session, AvatarFilesFromOtherModelsOrDamagedAreRejected) {
  TempDir dir;
  Session session(TinyOptions(3));
  const Avatar avatar = MakeAvatar(session);
  session.SaveAvatar(avatar, dir.path() / "a.avatar");
  Session other_seed(TinyOptions(4));
  EXPECT_THROW(other_seed.LoadAvatar(dir.path() / "a.avatar"), ModelLoad);
  EXPECT_THROW(other_seed.Animate(avatar, {}, ViewPose{}, RenderMode::kPreview), InvalidInput);
  std::string bytes = ReadFileBytes(dir.path() / "a.avatar");
  WriteBytesAtomically(dir.path() / "cut.avatar", bytes.substr(0, bytes.size() / 3));
  EXPECT_THROW(session.LoadAvatar(dir.path() / "cut.avatar"), ModelLoad);
  // A model checkpoint is not an avatar.
  GohaModel model(ModelConfig::Tiny());
  SaveModelCheckpoint(dir.path() / "m.ckpt", model, {});
  EXPECT_THROW(session.LoadAvatar(dir.path() / "m.ckpt"), ModelLoad);
  EXPECT_THROW(session.LoadAvatar(dir.path() / "missing.avatar"), Io);
}

TEST(Session, CheckpointSessionEqualsRandomSessionWithSameWeights) {
  TempDir dir;
  CheckpointInfo info;
  info.sr_trained = true;  // random weights run their (random) SR too
  testing::SaveTinyCheckpoint(dir / "m.ckpt", 7, info);
  SessionOptions from_file;
  from_file.checkpoint = (dir.path() / "m.ckpt").string();
  Session a(from_file);
  Session b(TinyOptions(7));
  EXPECT_EQ(a.Info().origin, "checkpoint");
  EXPECT_TRUE(a.Info().sr_trained);
  EXPECT_EQ(a.Info().parameters, b.Info().parameters);
  EXPECT_EQ(a.Info().config_name, "tiny");
  EXPECT_EQ(a.Info().model_id.rfind("ckpt:", 0), 0u);
  const Frame fa = a.Animate(MakeAvatar(a), {{{"jawOpen", 0.4f}}}, ViewPose{30}, RenderMode::kFinal);
  const Frame fb = b.Animate(MakeAvatar(b), {{{"jawOpen", 0.4f}}}, ViewPose{30}, RenderMode::kFinal);
  EXPECT_TRUE(SameMat(fa.bgr, fb.bgr));
}

// The synthetic I_exp with morphable coefficients as well: `count` of them, jawOpen and smile the
// first two, Expression::coefficients added on top (what a network with expression bases reads).
class SyntheticCoefficientSource : public SyntheticExpressionSource {
 public:
  explicit SyntheticCoefficientSource(int count) : count_(count) {}
  int CoefficientCount() const override { return count_; }
  std::vector<float> Coefficients(const Expression& expression) const override {
    std::vector<float> beta(count_, 0.0f);
    beta[0] = expression.Get("jawOpen");
    beta[1] = expression.Get("smile");
    if (!expression.coefficients.empty()) {
      if (static_cast<int>(expression.coefficients.size()) != count_) throw InvalidInput("wrong coefficient count");
      for (int k = 0; k < count_; ++k) beta[k] += expression.coefficients[k];
    }
    return beta;
  }

 private:
  int count_;
};

double MeanAbsDiff(const cv::Mat& a, const cv::Mat& b) {
  cv::Mat diff;
  cv::absdiff(a, b, diff);
  const cv::Scalar m = cv::mean(diff);
  return (m[0] + m[1] + m[2]) / 3.0;
}

TEST(Session, ExpressionBasesModelMixesTeFromTheExpressionCoefficients) {
  TempDir dir;
  GohaModel model = testing::SaveTinyCheckpoint(dir / "bases.ckpt", 11, {}, /*expression_bases=*/true);
  const ModelConfig& config = model->config();
  SessionOptions o;
  o.checkpoint = (dir / "bases.ckpt").string();
  Session session(o);
  const int k = config.expression_coefficients;
  const Avatar avatar = MakeAvatar(session, FrontalFit(std::make_shared<SyntheticCoefficientSource>(k)));

  session.ResetCounters();
  Expression raw;  // driver-style raw coefficients
  raw.coefficients.assign(k, 0.0f);
  raw.coefficients[2] = 1.5f;
  const Frame neutral = session.Animate(avatar, {}, ViewPose{}, RenderMode::kStandard);
  const Frame jaw = session.Animate(avatar, {{{"jawOpen", 1.0f}}}, ViewPose{}, RenderMode::kStandard);
  const Frame driven = session.Animate(avatar, raw, ViewPose{15}, RenderMode::kStandard);
  const SessionCounters c = session.Counters();
  EXPECT_EQ(c.expression_images, 0);   // no I_exp: T_e comes from the coefficients
  EXPECT_EQ(c.expression_encoder, 3);  // one mix of the bases per new expression
  for (const Frame* f : {&neutral, &jaw, &driven}) {
    ASSERT_EQ(f->bgr.rows, config.render_size);
    EXPECT_TRUE(cv::checkRange(f->opacity));
    EXPECT_TRUE(cv::checkRange(f->depth));
  }
  const double jaw_change = MeanAbsDiff(neutral.bgr, jaw.bgr);
  const Frame driven_front = session.Animate(avatar, raw, ViewPose{}, RenderMode::kStandard);
  const double driven_change = MeanAbsDiff(neutral.bgr, driven_front.bgr);
  std::printf(
      "bases model: mean |frame difference| neutral vs jawOpen=1 %.2f, vs raw coefficient 2 = 1.5 %.2f "
      "(8-bit levels)\n",
      jaw_change, driven_change);
  EXPECT_GT(jaw_change, 0.5);
  EXPECT_GT(driven_change, 0.5);
  EXPECT_TRUE(SameMat(jaw.bgr, session.Animate(avatar, {{{"jawOpen", 1.0f}}}, ViewPose{}, RenderMode::kStandard).bgr));
  EXPECT_EQ(session.Counters().expression_encoder, 3);  // repeated expressions are cached

  // T_e of jawOpen = 1 is beta = (1, 0, ...) over std 1: the first basis itself.
  const torch::Tensor te = SessionAccess::ExpressionPlanes(session, avatar, {{{"jawOpen", 1.0f}}});
  ASSERT_TRUE(te.defined());
  EXPECT_TRUE(torch::allclose(te[0], model->expression_bases[0].detach(), 1e-5, 1e-6));
  EXPECT_TRUE(torch::isfinite(te).all().item<bool>());

  // An avatar whose expression source has no coefficients cannot drive such a network.
  const Avatar plain = MakeAvatar(session);
  EXPECT_THROW(session.Animate(plain, {}, ViewPose{}, RenderMode::kPreview), InvalidInput);
}

TEST(Session, StageOneWeightsUpsampleInsteadOfRunningTheUntrainedSr) {
  TempDir dir;
  testing::SaveTinyCheckpoint(dir / "m.ckpt", 7);  // sr_trained = false (stage I)
  SessionOptions o;
  o.checkpoint = (dir.path() / "m.ckpt").string();
  Session session(o);
  EXPECT_FALSE(session.Info().sr_trained);
  EXPECT_NE(DescribeModel(session.Info()).find("super-resolution not trained"), std::string::npos);
  const Avatar avatar = MakeAvatar(session);
  session.ResetCounters();
  const Frame standard = session.Animate(avatar, {}, ViewPose{10}, RenderMode::kStandard);
  const Frame final_frame = session.Animate(avatar, {}, ViewPose{10}, RenderMode::kFinal);
  EXPECT_EQ(session.Counters().super_resolutions, 0);
  EXPECT_FALSE(final_frame.super_resolved);
  EXPECT_TRUE(final_frame.upsampled);
  const ModelConfig c = ModelConfig::Tiny();
  ASSERT_EQ(final_frame.bgr.rows, c.sr_size);
  // The upsampled frame is the standard render scaled up: shrinking it back gives the render.
  cv::Mat back;
  cv::resize(final_frame.bgr, back, standard.bgr.size(), 0, 0, cv::INTER_AREA);
  cv::Mat diff;
  cv::absdiff(back, standard.bgr, diff);
  EXPECT_LT(cv::mean(diff)[0] + cv::mean(diff)[1] + cv::mean(diff)[2], 3 * 4.0);
}

TEST(Session, DefaultIsTheInstalledModelElseTheBundledOneElseAClearError) {
  TempDir dir;
  // Nothing installed in the data folder: the bundled model of the source tree loads.
  SessionOptions o;
  o.data_dir = dir.path().string();
  std::string origin;
  const std::filesystem::path bundled = ResolveCheckpoint(o, &origin);
  EXPECT_EQ(origin, "bundled");
  EXPECT_EQ(bundled.filename(), "goha-default.ckpt");
  EXPECT_TRUE(std::filesystem::exists(bundled)) << bundled;
  // A model installed in the data folder wins over the bundled one.
  std::filesystem::create_directories(dir.path() / "models");
  GohaModel tiny(ModelConfig::Tiny());
  SaveModelCheckpoint(dir.path() / "models" / "goha.ckpt", tiny, {});
  EXPECT_EQ(ResolveCheckpoint(o, &origin), dir.path() / "models" / "goha.ckpt");
  EXPECT_EQ(origin, "installed");
  Session installed(o);
  EXPECT_EQ(installed.Info().origin, "installed");
  EXPECT_EQ(installed.Info().config_name, "tiny");
  std::filesystem::remove(dir.path() / "models" / "goha.ckpt");
  // No bundled model either (an install whose resource folder lacks it): MissingData naming where it looked.
  TempDir empty;
  ::setenv("AVATAR_RESOURCE_DIR", empty.path().c_str(), 1);
  try {
    Session s(o);
    ADD_FAILURE() << "expected MissingData";
  } catch (const MissingData& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("No GOHA model found"), std::string::npos) << msg;
    EXPECT_NE(msg.find((empty.path() / "models").string()), std::string::npos) << msg;
    EXPECT_NE(msg.find("--checkpoint"), std::string::npos) << msg;
  }
  ::unsetenv("AVATAR_RESOURCE_DIR");
  // Random weights need no model file.
  EXPECT_EQ(ResolveCheckpoint(TinyOptions(), &origin), std::filesystem::path());
  EXPECT_EQ(origin, "random");
  SessionOptions bad = TinyOptions();
  bad.config = "huge";
  EXPECT_THROW(Session{bad}, InvalidOptions);
}

TEST(Session, BadInputsGiveTypedErrors) {
  Session session(TinyOptions());
  RunContext ctx;
  EXPECT_THROW(session.Animate(Avatar{}, {}, ViewPose{}, RenderMode::kPreview), InvalidInput);
  face::AlignedPortrait empty;
  EXPECT_THROW(session.ReconstructFromAnalysis(empty, FrontalFit(), ctx), InvalidInput);
  SourceFit nan_fit = FrontalFit();
  nan_fit.camera[3] = std::nanf("");
  EXPECT_THROW(session.ReconstructFromAnalysis(PortraitFromAlignedImage(SyntheticPortrait()), nan_fit, ctx),
               InvalidInput);
  SourceFit bad_fit = FrontalFit();
  bad_fit.camera[15] = 2.0f;  // last cam2world row must be (0,0,0,1)
  EXPECT_THROW(session.ReconstructFromAnalysis(PortraitFromAlignedImage(SyntheticPortrait()), bad_fit, ctx),
               InvalidInput);
  const Avatar avatar = MakeAvatar(session);
  EXPECT_THROW(session.Animate(avatar, {{{"frown", 1.0f}}}, ViewPose{}, RenderMode::kPreview), InvalidInput);
  EXPECT_THROW(session.Animate(avatar, {}, ViewPose{std::nan(""), 0}, RenderMode::kPreview), InvalidOptions);
  EXPECT_THROW(session.Animate(avatar, {}, ViewPose{0, 0, 0, -1}, RenderMode::kPreview), InvalidOptions);
  EXPECT_THROW(RenderModeFromName("ultra"), InvalidOptions);
  EXPECT_THROW(session.Reconstruct(cv::Mat(), ctx), InvalidInput);
}

TEST(Session, HardCasesStayFinite) {
  Session session(TinyOptions());
  RunContext ctx;
  // A tiny 8x8 portrait and an all-black one with an empty matte.
  const Avatar small =
      session.ReconstructFromAnalysis(PortraitFromAlignedImage(SyntheticPortrait(8)), FrontalFit(), ctx);
  face::AlignedPortrait black = PortraitFromAlignedImage(cv::Mat::zeros(512, 512, CV_8UC3));
  black.matte = cv::Mat::zeros(512, 512, CV_32FC1);
  const Avatar dark = session.ReconstructFromAnalysis(black, FrontalFit(), ctx);
  for (const Avatar* a : {&small, &dark}) {
    for (const ViewPose& v : {ViewPose{180, 0}, ViewPose{-179, -89.5}, ViewPose{0, 89.5, -180}, ViewPose{45, 0, 0, 9.0}}) {
      const Frame f = session.Animate(*a, {{{"jawOpen", 5.0f}, {"smile", -3.0f}}}, v, RenderMode::kFinal);
      EXPECT_TRUE(cv::checkRange(f.opacity));
      EXPECT_TRUE(cv::checkRange(f.depth));
    }
  }
}

TEST(Session, CancellationStopsReconstructAndAnimate) {
  Session session(TinyOptions());
  const Avatar avatar = MakeAvatar(session);
  RunContext ctx;
  ctx.RequestCancel();
  EXPECT_THROW(session.ReconstructFromAnalysis(PortraitFromAlignedImage(SyntheticPortrait()), FrontalFit(), ctx),
               Cancelled);
  EXPECT_THROW(session.Animate(avatar, {}, ViewPose{}, RenderMode::kPreview, &ctx), Cancelled);
  // Progress is reported while reconstructing.
  std::vector<double> fractions;
  RunContext progress([&](const Progress& p) { fractions.push_back(p.fraction); });
  session.ReconstructFromAnalysis(PortraitFromAlignedImage(SyntheticPortrait()), FrontalFit(), progress);
  ASSERT_GE(fractions.size(), 2u);
  EXPECT_DOUBLE_EQ(fractions.back(), 1.0);
}

TEST(Session, ConcurrentAnimateMatchesSerial) {
  // A cache of two expressions for three in use: the threads evict each other's entries.
  SessionOptions options = TinyOptions();
  options.expression_cache = 2;
  Session session(options);
  const Avatar avatar = MakeAvatar(session);
  std::vector<ViewPose> views;
  for (int i = 0; i < 6; ++i) views.push_back(ViewPose{-40.0 + 15 * i, -5.0 * (i % 3)});
  // Thread t renders frames t, t+2, t+4; the schedule gives every thread a new expression on
  // every frame, and the two threads different expressions at the same time (0, 0.5, 1 against
  // 0.5, 1, 0). The tiny random network's colours barely vary (8-bit frames can be equal), so
  // the float opacity and depth maps are compared too.
  auto expression = [](size_t i) {
    return Expression{{{"jawOpen", 0.5f * static_cast<float>((i / 2 + i % 2) % 3)}}};
  };
  for (size_t i = 0; i + 2 < views.size(); ++i) {
    ASSERT_FALSE(expression(i) == expression(i + 2)) << "thread " << i % 2 << " must change its expression";
  }
  for (size_t step = 0; 2 * step + 1 < views.size(); ++step) {
    ASSERT_FALSE(expression(2 * step) == expression(2 * step + 1)) << "the threads must differ at step " << step;
  }
  auto same = [](const Frame& a, const Frame& b) {
    return SameMat(a.bgr, b.bgr) && SameMat(a.opacity, b.opacity) && SameMat(a.depth, b.depth);
  };
  std::vector<Frame> serial;
  for (size_t i = 0; i < views.size(); ++i)
    serial.push_back(session.Animate(avatar, expression(i), views[i], RenderMode::kStandard));
  // Every expression must change the frame, or the comparison below would not test it.
  for (size_t a = 0; a < 3; ++a) {
    for (size_t b = a + 1; b < 3; ++b) {
      const Frame fa = session.Animate(avatar, Expression{{{"jawOpen", 0.5f * a}}}, views[0], RenderMode::kStandard);
      const Frame fb = session.Animate(avatar, Expression{{{"jawOpen", 0.5f * b}}}, views[0], RenderMode::kStandard);
      ASSERT_FALSE(same(fa, fb)) << "jawOpen " << 0.5 * a << " and " << 0.5 * b << " render the same";
    }
  }
  session.ResetCounters();
  std::vector<Frame> parallel(views.size());
  std::vector<std::thread> threads;
  for (int t = 0; t < 2; ++t) {
    threads.emplace_back([&, t] {
      for (size_t i = t; i < views.size(); i += 2) {
        parallel[i] = session.Animate(avatar, expression(i), views[i], RenderMode::kStandard);
      }
    });
  }
  for (auto& th : threads) th.join();
  for (size_t i = 0; i < views.size(); ++i) EXPECT_TRUE(same(serial[i], parallel[i])) << i;
  EXPECT_EQ(session.Counters().renders, static_cast<int64_t>(views.size()));
  // With two cache slots for three expressions, some expression planes had to be recomputed.
  EXPECT_GE(session.Counters().expression_encoder, 1);
}

TEST(Session, AnimateAtACameraLabel) {
  Session session(TinyOptions());
  const Avatar avatar = MakeAvatar(session);
  // The orbit view and the same camera as a label are one render.
  const std::array<float, 25> front = testing::FrontalCameraLabel();
  const Frame a = session.Animate(avatar, {{{"smile", 0.5f}}}, ViewPose{}, RenderMode::kStandard);
  const Frame b = session.Animate(avatar, {{{"smile", 0.5f}}}, front, RenderMode::kStandard);
  EXPECT_TRUE(SameMat(a.bgr, b.bgr));
  EXPECT_TRUE(SameMat(a.opacity, b.opacity));
  EXPECT_TRUE(SameMat(a.depth, b.depth));
  const Frame c = session.Animate(avatar, {{{"smile", 0.5f}}}, ViewPose{25}, RenderMode::kStandard);
  EXPECT_FALSE(SameMat(a.opacity, c.opacity));
  std::array<float, 25> bad = front;
  bad[0] = 2.0f;  // not a rotation
  EXPECT_THROW(session.Animate(avatar, {}, bad, RenderMode::kPreview), InvalidInput);
  bad = front;
  bad[5] = std::nanf("");
  EXPECT_THROW(session.Animate(avatar, {}, bad, RenderMode::kPreview), InvalidInput);
}

// Frames render with the inference skips by default (RenderSettings, SessionOptions::render_skips)
// and stay within the skips' bound of the full render; depth and alpha are computed only when asked.
TEST(Session, RenderSkipsAreOnByDefaultAndCloseToTheFullRender) {
  EXPECT_TRUE(SessionOptions().render_skips);
  const RenderSettings defaults;
  EXPECT_TRUE(defaults.early_termination && defaults.skip_missed_rays && defaults.skip_empty_space);
  EXPECT_TRUE(defaults.opacity && defaults.depth);
  const Session skipping(TinyOptions());
  SessionOptions off = TinyOptions();
  off.render_skips = false;
  const Session full(off);
  const Avatar avatar = MakeAvatar(skipping);
  for (const ViewPose& view : {ViewPose{}, ViewPose{35, -10}, ViewPose{170, 20}}) {
    SCOPED_TRACE(view.yaw);
    const Frame a = full.Animate(avatar, {}, view, RenderMode::kStandard);
    const Frame b = skipping.Animate(avatar, {}, view, RenderMode::kStandard);
    ASSERT_EQ(a.bgr.size(), b.bgr.size());
    cv::Mat diff;
    cv::absdiff(a.bgr, b.bgr, diff);
    const cv::Scalar levels = cv::mean(diff);
    // 1e-3 of the [-1,1] range is 0.13 grey levels; 8-bit rounding adds at most one level per pixel.
    EXPECT_LE((levels[0] + levels[1] + levels[2]) / 3.0, 0.5);
    cv::Mat opacity_diff;
    cv::absdiff(a.opacity, b.opacity, opacity_diff);
    EXPECT_LE(cv::mean(opacity_diff)[0], 1e-3);
  }
  RenderSettings lean;
  lean.opacity = false;
  lean.depth = false;
  const Frame with = skipping.Animate(avatar, {}, avatar.SourceCamera(), RenderSettings{});
  const Frame without = skipping.Animate(avatar, {}, avatar.SourceCamera(), lean);
  EXPECT_FALSE(with.opacity.empty());
  EXPECT_FALSE(with.depth.empty());
  EXPECT_TRUE(without.opacity.empty());
  EXPECT_TRUE(without.depth.empty());
  EXPECT_TRUE(SameMat(with.bgr, without.bgr));
}

TEST(Expression, KeyIsCanonical) {
  Expression a{{{"smile", 0.5f}, {"jawOpen", 0.25f}}};
  Expression b{{{"jawOpen", 0.25f}, {"smile", 0.5f}, {"blink", 0.0f}}};
  EXPECT_EQ(a.Key(), b.Key());
  EXPECT_EQ(a.Key(), "jawOpen=0.25,smile=0.5");
  EXPECT_EQ(Expression{}.Key(), "");
  // Coefficients and the absolute flag are part of the expression, so part of the key.
  Expression c = a;
  c.coefficients = {0.1f, -2.0f, 0.0f};
  Expression d = c;
  d.coefficients_absolute = true;
  Expression e = c;
  e.coefficients[0] = std::nextafter(0.1f, 1.0f);  // one float step: a different expression
  EXPECT_EQ(c.Key(), "jawOpen=0.25,smile=0.5|c=0.100000001,-2,0");
  EXPECT_EQ(d.Key(), c.Key() + "|absolute");
  EXPECT_NE(e.Key(), c.Key());
  Expression only_absolute;
  only_absolute.coefficients_absolute = true;
  EXPECT_EQ(only_absolute.Key(), "|absolute");
  EXPECT_FALSE(c == d);
  EXPECT_TRUE(c == Expression(c));
}

}  // namespace
}  // namespace avatar
