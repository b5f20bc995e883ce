#pragma once
// Reads a dataset written by `avatar-studio dataset build` (core/tools/dataset_build.h) with
// LibTorch only: dataset.json plus one tensor shard per split (shards/train.pt, shards/val.pt,
// a pickled dict of uint8 images, float labels and coefficients, and int64 pair indices).
// A dataset built with --synthetic N also has shards/synthetic.pt (same format, pair kind
// kSynthetic, training identities only), opened as the split "synthetic"; the loader mixes it
// into the training pairs only when LoaderOptions::synthetic_fraction > 0.
// The loader shuffles with its own seed, so two loaders with one seed give the same batches.

#include <cstdint>
#include <string>
#include <vector>

#include <torch/torch.h>

#include "core/train/sample.h"

namespace avatar::train {

class TrainDataset {
 public:
  // Opens `split` ("train", "val" or "synthetic") of the dataset in `dir`. Throws InvalidOptions
  // for an unknown split, Io for a missing file, InvalidInput for a corrupted dataset.json or
  // shard (naming the file and what is wrong) or a "synthetic" split the dataset does not have.
  static TrainDataset Open(const std::string& dir, const std::string& split);
  // Whether dataset.json in `dir` lists a synthetic shard (false when it is unreadable).
  static bool HasSynthetic(const std::string& dir);

  int64_t size() const { return pairs_.size(0); }    // pairs
  int64_t frames() const { return image_.size(0); }  // distinct frames
  int64_t image_size() const { return image_size_; }
  const std::string& split() const { return split_; }
  int64_t CountKind(PairKind kind) const;
  // Distinct identity ids of this split.
  std::vector<int64_t> Identities() const;
  // Identity id of pair `index` (its source frame's) without loading the pair. Throws InvalidInput
  // for an index out of range.
  int64_t PairIdentity(int64_t index) const;

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
  // Share of synthetic pairs in each epoch, in [0,1]: 0 (the default) reads the dataset's pairs
  // only; f > 0 adds round(f/(1-f) x pairs) synthetic pairs per epoch (drawn without repetition
  // until the synthetic split is used up, then again), f = 1 reads the synthetic pairs only.
  // Needs the synthetic split given to the loader.
  double synthetic_fraction = 0.0;
  // Throws InvalidOptions.
  void Validate() const;
};

// Batches of a dataset in a seeded order; epoch e's order depends on (seed, e) only.
class DataLoader {
 public:
  // `dataset` (and `synthetic`, may be null when synthetic_fraction is 0) must outlive the
  // loader. Throws InvalidOptions (options; a synthetic fraction without synthetic pairs) and
  // InvalidInput (no pairs).
  DataLoader(const TrainDataset& dataset, const LoaderOptions& options);
  DataLoader(const TrainDataset& dataset, const TrainDataset* synthetic, const LoaderOptions& options);
  // The next batch of the current epoch; false at its end (then call StartEpoch).
  bool Next(TrainBatch* batch);
  void StartEpoch(int64_t epoch);
  int64_t BatchesPerEpoch() const;

 private:
  const TrainDataset& dataset_;
  const TrainDataset* synthetic_ = nullptr;
  LoaderOptions options_;
  // Entries < dataset_.size() are its pairs; entry dataset_.size() + j is synthetic pair j.
  std::vector<int64_t> order_;
  size_t position_ = 0;
};

}  // namespace avatar::train
