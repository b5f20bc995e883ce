#pragma once
// One training pair as the trainer sees it. The data factory (core/train/dataset.*) writes
// pairs; the loader returns them stacked into a TrainBatch. LibTorch types only, so the
// trainer builds against any LibTorch (CPU or CUDA) without OpenCV.
//
// Conventions: images are float [3,S,S] RGB in [-1,1] with a black (-1) background outside
// the person matte; masks are float [1,S,S] in [0,1]; labels are EG3D 25-float camera labels
// (row-major cam2world 4x4, then row-major normalised intrinsics 3x3) in render::Camera's
// convention. S is the dataset's image size (dataset.json "size").

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include <torch/torch.h>

namespace avatar::train {

// Where a pair comes from.
enum class PairKind : int64_t {
  kPhoto = 0,      // a real photo: source = target
  kClip = 1,       // two frames of one real clip
  kSynthetic = 2,  // renders of a synthetic 2.5D head (multi-view and/or expression change)
};

struct TrainSample {
  torch::Tensor source;            // I_s [3,S,S]
  torch::Tensor source_matte;      // [1,S,S] person matte of the source
  torch::Tensor source_eye_mouth;  // [1,S,S] 1 on eyes, brows, lips and inner mouth
  torch::Tensor source_label;      // [25] source camera C_s
  torch::Tensor target;            // I_t [3,S,S]
  torch::Tensor target_matte;      // [1,S,S]
  torch::Tensor target_label;      // [25] target camera C_t
  torch::Tensor expression_image;  // I_exp [3,S,S]: source identity, target expression, frontal camera
  torch::Tensor neutral_image;     // I_neu [3,S,S]: source identity, zero expression, source camera
  torch::Tensor neutral_mask;      // M_neu [1,S,S]: coverage of the morphable face in I_neu
  torch::Tensor target_expression; // [K] morphable expression coefficients of the target
  PairKind kind = PairKind::kPhoto;
  int64_t identity = -1;           // identity id (dataset-wide)
};

// Samples stacked along a new batch dimension (images [B,3,S,S], labels [B,25], ...).
struct TrainBatch {
  torch::Tensor source, source_matte, source_eye_mouth, source_label;
  torch::Tensor target, target_matte, target_label;
  torch::Tensor expression_image, neutral_image, neutral_mask, target_expression;
  torch::Tensor kind;      // [B] int64 (PairKind)
  torch::Tensor identity;  // [B] int64

  int64_t size() const { return source.defined() ? source.size(0) : 0; }
  // Every tensor moved/cast to `device` (images float32).
  TrainBatch To(const torch::Device& device) const;
  // Every defined tensor through `f` (undefined ones stay undefined), e.g. a slice of the samples.
  TrainBatch Map(const std::function<torch::Tensor(const torch::Tensor&)>& f) const;
};

// Stacks samples (all of one image size). Throws InvalidInput on mismatched shapes.
TrainBatch Collate(const std::vector<TrainSample>& samples);

}  // namespace avatar::train
