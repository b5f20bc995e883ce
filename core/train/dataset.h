#pragma once
// Reads a dataset written by `avatar-studio dataset build` (core/pipeline/dataset_build.h) with
// LibTorch only: dataset.json plus one tensor shard per split (shards/train.pt, shards/val.pt,
// a pickled dict of uint8 images, float labels and coefficients, and int64 pair indices).
// The loader shuffles with its own seed, so two loaders with one seed give the same batches.

#include <cstdint>
#include <string>
#include <vector>

#include <torch/torch.h>

#include "core/train/sample.h"

namespace avatar::train {

class TrainDataset {
 public:
  // Opens `split` ("train" or "val") of the dataset in `dir`. Throws InvalidOptions for an
  // unknown split, Io for a missing file, InvalidInput for a corrupted dataset.json or shard
  // (naming the file and what is wrong).
  static TrainDataset Open(const std::string& dir, const std::string& split);

  int64_t size() const { return pairs_.size(0); }    // pairs
  int64_t frames() const { return image_.size(0); }  // distinct frames
  int64_t image_size() const { return image_size_; }
  const std::string& split() const { return split_; }
  int64_t CountKind(PairKind kind) const;
  // Distinct identity ids of this split.
  std::vector<int64_t> Identities() const;

  // Pair `index` in [0,size()). Images in [-1,1] with a black background outside the matte.
  // Throws InvalidInput for an index out of range.
  TrainSample Get(int64_t index) const;

 private:
  std::string split_;
  int64_t image_size_ = 0;
  // Shard tensors (see dataset_build.h): uint8 [N,C,S,S] images, float labels [N,25] and
  // expressions [N,K], int64 identity [N], pairs [P,2], pair_kind [P].
  torch::Tensor image_, matte_, eye_mouth_, expression_image_, neutral_image_, neutral_mask_;
  torch::Tensor label_, expression_, identity_, pairs_, pair_kind_;
};

struct LoaderOptions {
  // Pairs per batch.
  int batch_size = 8;
  // Seed of the shuffling.
  uint64_t seed = 1;
  // Shuffle the pairs every epoch.
  bool shuffle = true;
  // Drop the last incomplete batch of an epoch.
  bool drop_last = false;
  // Throws InvalidOptions.
  void Validate() const;
};

// Batches of a dataset in a seeded order; epoch e's order depends on (seed, e) only.
class DataLoader {
 public:
  // `dataset` must outlive the loader.
  DataLoader(const TrainDataset& dataset, const LoaderOptions& options);
  // The next batch of the current epoch; false at its end (then call StartEpoch).
  bool Next(TrainBatch* batch);
  void StartEpoch(int64_t epoch);
  int64_t BatchesPerEpoch() const;

 private:
  const TrainDataset& dataset_;
  LoaderOptions options_;
  std::vector<int64_t> order_;
  size_t position_ = 0;
};

}  // namespace avatar::train
