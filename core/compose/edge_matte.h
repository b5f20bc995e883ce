#pragma once
// The photo's person edge cleaned for the detail path. A segmentation matte is soft and slightly
// off the true outline (on franck_01829 it stays above 0.8 for 3-4 px of blue background past the
// jaw), and the photo's pixels along the outline mix the person with the background behind. The
// warps carry those pixels to every view, so a turned head shows a rim, or at a stretched jaw a
// patch, of the photo's background colour. Near the matte's outline each pixel is split between
// the local person colour F and background colour B (both from pixels well inside and well
// outside the outline, filled over the band by push-pull): its colour c lies near the segment
// F-B, and the share of B along it says how much of the pixel is background. The edge's matte
// keeps the smaller of the segmentation's and this colour estimate, and its colour is the person's
// part of c (the background share taken out). Where F and B are alike, or the background around
// the pixel is busy (its colours spread far around B), the colour cannot tell them apart, and the
// segmentation's matte and the photo's colour stay.

#include <opencv2/core.hpp>

namespace avatar::compose {

struct EdgeMatteOptions {
  // Half-width of the band around the matte's 0.5 outline that is refined, and the depth inside
  // (outside) it from which the person's (background's) colours are taken, as a fraction of the
  // image height.
  double band = 0.016;
  // F and B closer than this (Euclidean, in 0..255 BGR levels) leave the pixel as it is.
  double min_contrast = 40.0;
  // The background's local spread (the root of its colours' summed variance around B) above this
  // fraction of |F - B| leaves the pixel as it is: unmixing needs a plain background. Grace
  // Hopper's flag behind her cap spreads 0.5-1.5 |F - B| (holes in the cap at 0.25 without the
  // rule), franck's blue screen under 0.1.
  double max_background_spread = 0.25;
  // Matte below which the pixel's colour is the local person colour F itself instead of the
  // background share taken out of c (dividing by a small share amplifies noise).
  float min_solve = 0.25f;
  // Throws InvalidOptions.
  void Validate() const;
};

struct EdgeMatte {
  cv::Mat bgr;    // CV_8UC3 the photo with the outline's background share taken out
  cv::Mat matte;  // CV_32FC1 in [0,1], at most the segmentation's
};

// `bgr` (CV_8UC3) and `matte` (CV_32FC1 in [0,1], same size). A matte without a person or without
// background (all above or all below 0.5) comes back as it is. Throws InvalidInput for empty or
// mismatched images.
EdgeMatte RefineEdgeMatte(const cv::Mat& bgr, const cv::Mat& matte, const EdgeMatteOptions& options = {});

}  // namespace avatar::compose
