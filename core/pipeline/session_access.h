#pragma once
// Internal door of core/pipeline into a Session and its Avatars, for code that works on the
// network and the cached planes directly (per-portrait refinement, core/pipeline/refine.h).
// LibTorch types here; session.h stays free of them. Not for the GUI or the CLI.

#include <string>

#include <opencv2/core.hpp>
#include <torch/torch.h>

#include "core/model/goha_model.h"
#include "core/pipeline/session.h"

namespace avatar {

struct SessionAccess {
  // The session's network (shared: only forward passes, never parameter updates or .grad).
  static GohaModel Model(const Session& session);
  // Throws InvalidInput when the avatar is empty or was made with another model than the session's.
  static void CheckAvatar(const Session& session, const Avatar& avatar);
  // The avatar's cached planes T_c, T_p [1,3,C,P,P] (inference tensors: clone before autograd).
  static torch::Tensor Canonical(const Avatar& avatar);
  static torch::Tensor Appearance(const Avatar& avatar);
  // T_e of `expression` for this avatar's expression source (no cache, no gradient); undefined
  // when the avatar has no expression source.
  static torch::Tensor ExpressionPlanes(const Session& session, const Avatar& avatar, const Expression& expression);
  // A new avatar (new cache id) equal to `avatar` but with these planes (finite, of its shape)
  // and refinement summary (JSON text, see Avatar::RefinementInfo). Throws InvalidInput.
  static Avatar WithPlanes(const Avatar& avatar, const torch::Tensor& canonical, const torch::Tensor& appearance,
                           const std::string& refinement_json);
  // BGR8 image -> RGB [1,3,size,size] in [-1,1]; mask (8-bit or float) -> [1,1,size,size] in
  // [0,1], `fill` when empty. As the session converts its inputs. Throws InvalidInput.
  static torch::Tensor ImageTensor(const cv::Mat& bgr, int size, const char* what);
  static torch::Tensor MaskTensor(const cv::Mat& mask, int size, float fill, const char* what);
};

}  // namespace avatar
