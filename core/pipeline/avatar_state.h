#pragma once
// The state behind an Avatar (session.h): the cached per-source network planes and what the
// session needs to animate them. Internal to core/pipeline (LibTorch types); shared by the
// session (session.cc), the avatar file format (avatar_file.cc) and SessionAccess.

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <string>

#include <opencv2/core.hpp>
#include <torch/torch.h>

#include "core/face/face_types.h"
#include "core/model/goha_model.h"
#include "core/morphable/fitter.h"
#include "core/pipeline/source_fit.h"

namespace avatar {

// What the photo's detail path (detail_source.h) needs of the portrait beyond the planes: the
// aligned crop with its matte and eye/mouth mask and the morphable fit. Kept with avatars made
// from a portrait analysis and stored in .avatar files, so that a saved avatar renders with the
// detail path (AnalysisFromFit rebuilds the rest).
struct AvatarPortrait {
  face::AlignedPortrait portrait;  // image_unmatted, matte, eye_mouth_mask, landmarks (image: matted crop)
  morphable::FitResult fit;        // fit.image_size = the crop's size
};

struct AvatarState {
  ModelConfig config;
  std::string model_id;
  uint64_t id = 0;                 // unique within the process (cache key)
  torch::Tensor canonical;         // T_c [1,3,C,P,P]
  torch::Tensor appearance;        // T_p [1,3,C,P,P]
  torch::Tensor base;              // T_c + T_p
  std::array<float, 25> camera{};  // C_s
  cv::Mat source;                  // [512,512] CV_8UC3 aligned portrait
  std::shared_ptr<const ExpressionImageSource> expressions;
  std::string refinement;          // JSON summary of the refinement of these planes ("" = one-shot)
  std::shared_ptr<const AvatarPortrait> portrait;  // null: made without an analysis, or an older file
};

// A fresh process-wide avatar id (for AvatarState::id).
inline uint64_t NextAvatarId() {
  static std::atomic<uint64_t> next{1};
  return next++;
}

}  // namespace avatar
