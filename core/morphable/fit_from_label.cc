// FitFromLabel lives apart from the fitter: the .avatar reader (and with it the fuzz build,
// cmake/AvatarFuzzSources.cmake) needs it without the optimiser and the morphable model.
#include "core/morphable/fitter.h"

namespace avatar::morphable {

FitResult FitFromLabel(const Alpha& alpha, const Beta& beta, float scale, const CameraLabel& label,
                       cv::Size image_size) {
  const PinholeCamera cam = PinholeCamera::FromLabel(label);
  FitResult fit;
  fit.alpha = alpha;
  fit.beta = beta;
  fit.scale = scale;
  fit.rotation = cam.world_to_cam;
  fit.translation = -(cam.world_to_cam * cam.centre);
  fit.camera = label;
  fit.image_size = image_size;
  return fit;
}

}  // namespace avatar::morphable
