#pragma once
// Expression quantities measured on 468-point face shapes (facemesh landmarks or model
// vertices), in units of the 3D distance between the eye centres. They define the named
// controls (see builder.h) and check them in tests.

#include <vector>

#include <opencv2/core.hpp>

#include "core/face/face_types.h"

namespace avatar::morphable {

struct ExpressionMeasures {
  double lip_gap = 0.0;         // inner upper lip (13) to inner lower lip (14)
  double mouth_width = 0.0;     // mouth corner (61) to mouth corner (291)
  double corner_lift = 0.0;     // height of the mouth corners above the inner-lip midpoint
  double brow_height = 0.0;     // brow middle (105/334) above the upper eyelid (159/386), both sides averaged
  double brow_inner_gap = 0.0;  // inner brow ends (107 to 336)
  double eye_open_right = 0.0;  // subject's right eyelids (159 to 145)
  double eye_open_left = 0.0;   // subject's left eyelids (386 to 374)
  double lip_protrusion = 0.0;  // lip centres (0, 17) in front of the mouth corners
};

// Measures a shape in the model frame (y up, z towards the viewer). Needs 468 points.
ExpressionMeasures MeasureShape(const std::vector<cv::Point3f>& model_frame_points);
// Measures facemesh landmarks (image frame: y down, smaller z closer) by flipping y and z.
ExpressionMeasures MeasureLandmarks(const face::Landmarks& landmarks);

}  // namespace avatar::morphable
