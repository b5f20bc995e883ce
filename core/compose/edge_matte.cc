#include "core/compose/edge_matte.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>

#include "core/util/error.h"
#include "core/util/push_pull.h"

namespace avatar::compose {

void EdgeMatteOptions::Validate() const {
  AVATAR_CHECK_OPTION(std::isfinite(band) && band > 0.0 && band <= 0.25)
      << "the edge band must be in (0, 0.25] of the image height, got " << band;
  AVATAR_CHECK_OPTION(std::isfinite(min_contrast) && min_contrast >= 0.0)
      << "the edge's colour contrast must be a finite number >= 0, got " << min_contrast;
  AVATAR_CHECK_OPTION(std::isfinite(max_background_spread) && max_background_spread >= 0.0)
      << "the edge's background spread must be a finite number >= 0, got " << max_background_spread;
  AVATAR_CHECK_OPTION(std::isfinite(min_solve) && min_solve > 0.0f && min_solve <= 1.0f)
      << "the edge's smallest solved share must be in (0, 1], got " << min_solve;
}

EdgeMatte RefineEdgeMatte(const cv::Mat& bgr, const cv::Mat& matte, const EdgeMatteOptions& options) {
  options.Validate();
  AVATAR_CHECK_INPUT(!bgr.empty() && bgr.type() == CV_8UC3) << "edge matte: the photo must be an 8-bit BGR image";
  AVATAR_CHECK_INPUT(matte.type() == CV_32FC1 && matte.size() == bgr.size())
      << "edge matte: the matte must be CV_32FC1 of the photo's size";
  EdgeMatte out{bgr.clone(), matte.clone()};
  cv::patchNaNs(out.matte, 0.0);
  const cv::Mat person = out.matte >= 0.5f;
  const int count = cv::countNonZero(person);
  if (count == 0 || count == static_cast<int>(person.total())) return out;

  // Distance to the outline from either side (pixels).
  cv::Mat inside, outside;
  cv::distanceTransform(person, inside, cv::DIST_L2, 3);
  cv::distanceTransform(~person, outside, cv::DIST_L2, 3);
  const float band = static_cast<float>(std::max(1.0, options.band * bgr.rows));
  const cv::Mat known_person = inside > band, known_background = outside > band;
  if (cv::countNonZero(known_person) == 0 || cv::countNonZero(known_background) == 0) return out;
  cv::Mat colour;
  bgr.convertTo(colour, CV_32FC3);
  // The background's colour and how much it varies around each pixel: both filled over the band
  // from the background beyond it, then averaged over half the band's width (push-pull alone
  // keeps the finest detail next to the known pixels, e.g. the one stripe of a flag nearest to the
  // outline). Unmixing needs a plain background (a wall, a screen); behind a busy one (a flag, a
  // room) the local mean is no pixel's colour and the split would punch holes in the person.
  const cv::Mat f = PushPullFill(colour, known_person);
  cv::Mat b = PushPullFill(colour, known_background), b2 = PushPullFill(colour.mul(colour), known_background);
  const double sigma = std::max(1.0, band / 2.0);
  cv::GaussianBlur(b, b, cv::Size(), sigma, sigma, cv::BORDER_REPLICATE);
  cv::GaussianBlur(b2, b2, cv::Size(), sigma, sigma, cv::BORDER_REPLICATE);
  const float max_spread = static_cast<float>(options.max_background_spread);
  const float min_contrast2 = static_cast<float>(options.min_contrast * options.min_contrast);
  // The colour's estimate of the person's share, where the band lets it speak (1 elsewhere).
  cv::Mat share_alpha(bgr.size(), CV_32FC1, cv::Scalar(1.0f));
  cv::parallel_for_(cv::Range(0, bgr.rows), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      for (int x = 0; x < bgr.cols; ++x) {
        if (inside.at<float>(y, x) > band || outside.at<float>(y, x) > band) continue;
        const cv::Vec3f fc = f.at<cv::Vec3f>(y, x), bc = b.at<cv::Vec3f>(y, x), c = colour.at<cv::Vec3f>(y, x);
        const cv::Vec3f fb = bc - fc;
        const float len2 = fb.dot(fb);
        if (!(len2 >= min_contrast2) || len2 <= 0.0f) continue;
        const cv::Vec3f b2c = b2.at<cv::Vec3f>(y, x);
        const float variance = std::max(0.0f, (b2c[0] - bc[0] * bc[0]) + (b2c[1] - bc[1] * bc[1]) + (b2c[2] - bc[2] * bc[2]));
        if (!(variance <= max_spread * max_spread * len2)) continue;  // a busy background here
        share_alpha.at<float>(y, x) = 1.0f - std::clamp((c - fc).dot(fb) / len2, 0.0f, 1.0f);
      }
    }
  });
  // The background's rim is a band along the outline; a lone pixel inside the person whose colour
  // happens to lean towards the background's (a highlight, a bluish strand) is no hole: a 3x3
  // closing fills such pixels from their neighbours.
  cv::morphologyEx(share_alpha, share_alpha, cv::MORPH_CLOSE, cv::Mat::ones(3, 3, CV_8UC1));
  const float solve = options.min_solve;
  cv::parallel_for_(cv::Range(0, bgr.rows), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      for (int x = 0; x < bgr.cols; ++x) {
        const float alpha = share_alpha.at<float>(y, x);
        if (alpha >= 1.0f) continue;
        const cv::Vec3f fc = f.at<cv::Vec3f>(y, x), bc = b.at<cv::Vec3f>(y, x), c = colour.at<cv::Vec3f>(y, x);
        float& m = out.matte.at<float>(y, x);
        m = std::min(m, alpha);
        // The person's part of c: solved from c = alpha F + (1 - alpha) B where alpha is large
        // enough, blending to the local person colour below.
        cv::Vec3f person_colour = fc;
        if (alpha >= solve) {
          const cv::Vec3f solved = (c - (1.0f - alpha) * bc) / alpha;
          const float w = std::min(1.0f, (alpha - solve) / solve);
          person_colour = w * solved + (1.0f - w) * fc;
        }
        cv::Vec3b& px = out.bgr.at<cv::Vec3b>(y, x);
        for (int k = 0; k < 3; ++k) px[k] = cv::saturate_cast<uchar>(person_colour[k]);
      }
    }
  });
  return out;
}

}  // namespace avatar::compose
