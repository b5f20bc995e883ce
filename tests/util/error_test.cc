#include "core/util/error.h"

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <torch/torch.h>

namespace avatar {
namespace {

TEST(Error, CheckPassesSilently) {
  int evaluated = 0;
  EXPECT_NO_THROW(AVATAR_CHECK(++evaluated == 1) << "never shown");
  EXPECT_EQ(evaluated, 1);  // The condition is evaluated exactly once.
}

TEST(Error, CheckThrowsInternalErrorWithLocationAndMessage) {
  try {
    AVATAR_CHECK(1 + 1 == 3) << "value was " << 2;
    FAIL() << "no exception";
  } catch (const InternalError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("error_test.cc"), std::string::npos) << what;
    EXPECT_NE(what.find("1 + 1 == 3"), std::string::npos) << what;
    EXPECT_NE(what.find("value was 2"), std::string::npos) << what;
    EXPECT_STREQ(e.Kind(), "internal");
  }
}

TEST(Error, TypedChecksThrowTheirTypeWithThePlainMessage) {
  try {
    AVATAR_CHECK_INPUT(false) << "no face found in 'a.jpg'";
    FAIL() << "no exception";
  } catch (const InvalidInput& e) {
    EXPECT_EQ(std::string(e.what()), "no face found in 'a.jpg'");
    EXPECT_STREQ(e.Kind(), "invalid_input");
  }
  EXPECT_THROW(AVATAR_CHECK_OPTION(false) << "x", InvalidOptions);
  EXPECT_THROW(AVATAR_CHECK_AS(ModelLoad, false) << "x", ModelLoad);
}

TEST(Error, EveryErrorIsAnAvatarErrorAndARuntimeError) {
  EXPECT_THROW(throw Io("x"), Error);
  EXPECT_THROW(throw MissingData("x"), std::runtime_error);
  EXPECT_THROW(throw Cancelled("x"), Error);
}

TEST(Error, RethrowTranslatesForeignExceptionsWithContext) {
  try {
    try {
      auto a = torch::zeros({2, 3});
      auto b = torch::zeros({4, 5});
      (void)torch::mm(a, b);
    } catch (...) {
      RethrowAsAvatarError("portrait.jpg");
    }
    FAIL() << "no exception";
  } catch (const InternalError& e) {
    const std::string what = e.what();
    EXPECT_EQ(what.rfind("portrait.jpg: ", 0), 0u) << what;
    EXPECT_EQ(what.find("frame #"), std::string::npos) << "backtrace leaked: " << what;
  }
  try {
    try {
      cv::Mat m(2, 2, CV_8UC1);
      (void)m.row(5);
    } catch (...) {
      RethrowAsAvatarError("x.png");
    }
    FAIL() << "no exception";
  } catch (const InvalidInput& e) {
    EXPECT_EQ(std::string(e.what()).rfind("x.png: ", 0), 0u);
  }
  EXPECT_THROW(
      {
        try {
          throw Cancelled("stop");
        } catch (...) {
          RethrowAsAvatarError("ctx");
        }
      },
      Cancelled);
}

}  // namespace
}  // namespace avatar
