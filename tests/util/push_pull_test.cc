// Push-pull gap filling (core/util/push_pull.h): a constant is filled with itself, fills lie
// between the known values around them and lean to the nearer one, channels fill alike, nothing
// known gives zeros, and bad inputs are refused.
#include <gtest/gtest.h>

#include <opencv2/core.hpp>

#include "core/util/error.h"
#include "core/util/push_pull.h"

namespace avatar {
namespace {

TEST(PushPull, AConstantFillsEveryGapWithItself) {
  cv::Mat values(37, 53, CV_32FC3, cv::Scalar(0.25f, 0.5f, 0.75f));
  cv::Mat known = cv::Mat::zeros(values.size(), CV_8UC1);
  known(cv::Rect(5, 7, 4, 3)).setTo(255);
  values.setTo(cv::Scalar::all(9.0f), known == 0);  // whatever lies in the gaps is ignored
  const cv::Mat filled = PushPullFill(values, known);
  ASSERT_EQ(filled.type(), CV_32FC3);
  ASSERT_EQ(filled.size(), values.size());
  for (int c = 0; c < 3; ++c) {
    double lo = 0, hi = 0;
    cv::Mat channel;
    cv::extractChannel(filled, channel, c);
    cv::minMaxLoc(channel, &lo, &hi);
    EXPECT_NEAR(lo, 0.25 * (c + 1), 1e-5);
    EXPECT_NEAR(hi, 0.25 * (c + 1), 1e-5);
  }
}

TEST(PushPull, AGapBetweenTwoValuesTakesValuesBetweenThemLeaningToTheNearer) {
  cv::Mat values(32, 64, CV_32FC1, cv::Scalar(0.0f));
  cv::Mat known = cv::Mat::zeros(values.size(), CV_8UC1);
  values(cv::Rect(0, 0, 8, 32)).setTo(1.0f);
  values(cv::Rect(56, 0, 8, 32)).setTo(3.0f);
  known(cv::Rect(0, 0, 8, 32)).setTo(255);
  known(cv::Rect(56, 0, 8, 32)).setTo(255);
  const cv::Mat filled = PushPullFill(values, known);
  double lo = 0, hi = 0;
  cv::minMaxLoc(filled, &lo, &hi);
  EXPECT_GE(lo, 1.0 - 1e-5);
  EXPECT_LE(hi, 3.0 + 1e-5);
  EXPECT_LT(filled.at<float>(16, 10), 2.0f);
  EXPECT_GT(filled.at<float>(16, 53), 2.0f);
  EXPECT_LT(filled.at<float>(16, 10), filled.at<float>(16, 32));
  EXPECT_LT(filled.at<float>(16, 32), filled.at<float>(16, 53));
}

TEST(PushPull, NothingKnownGivesZerosAndBadInputsAreRefused) {
  const cv::Mat values(8, 8, CV_32FC1, cv::Scalar(5.0f));
  const cv::Mat none = PushPullFill(values, cv::Mat::zeros(8, 8, CV_8UC1));
  EXPECT_EQ(cv::countNonZero(none), 0);
  EXPECT_THROW(PushPullFill(cv::Mat(8, 8, CV_8UC1), cv::Mat::zeros(8, 8, CV_8UC1)), InvalidInput);
  EXPECT_THROW(PushPullFill(values, cv::Mat::zeros(4, 8, CV_8UC1)), InvalidInput);
  EXPECT_THROW(PushPullFill(values, cv::Mat::zeros(8, 8, CV_32FC1)), InvalidInput);
}

}  // namespace
}  // namespace avatar
