#pragma once
// Does a driven avatar's mouth follow its driver? (issue 34's live acceptance: the correlation of
// jaw opening between driver and output over a talking clip.) Each driver frame and the avatar
// frame it drove are measured by the same face analysis (FaceMetrics: detection, facemesh
// landmarks), the mouth opening of both (MouthOpening: the inner lips' gap over the face height)
// is taken, and the Pearson correlation over the pairs with a face in both is reported.

#include <vector>

#include <opencv2/core.hpp>

#include "core/tools/face_metrics.h"
#include "core/util/run_context.h"

namespace avatar {

// Pearson correlation of two equally long series; NaN when shorter than 3 or when either is
// constant. Throws InvalidInput for unequal lengths.
double PearsonCorrelation(const std::vector<double>& a, const std::vector<double>& b);

struct MouthFollow {
  int pairs = 0;                        // pairs given
  int measured = 0;                     // pairs with a face in both frames
  std::vector<double> driver, output;   // mouth openings of the measured pairs, in order
  double correlation = 0.0;             // PearsonCorrelation(driver, output) (NaN: too few / constant)
};

// Measures every (driver[i], output[i]) pair (BGR8 frames). Throws InvalidInput for unequal
// counts; Cancelled.
MouthFollow MeasureMouthFollow(const std::vector<cv::Mat>& driver, const std::vector<cv::Mat>& output,
                               const face::FaceMetrics& faces, RunContext& ctx);

}  // namespace avatar
