#pragma once
// Data-parallel training over torch.distributed's C++ backend (c10d). W processes ("ranks") train
// one model: each takes a disjoint shard of every global batch (rank r: samples r*B/W ..
// (r+1)*B/W - 1 of the batch a single process would see, so every rank keeps the same data
// cursor), and after its backward pass the gradients are summed over the ranks and divided by W
// (ProcessGroupReducer, the trainer's GradientReducer). W processes at batch B/W therefore take
// the steps one process takes at batch B, as long as a step's randomness does not depend on the
// batch: the trainer's losses are batch means of per-sample terms, and every rank has the same
// seed, but the render jitter and the TV loss points are drawn per shard (the shapes follow the
// shard size), so in general the ranks' draws differ from the single process's; with
// TrainerOptions::deterministic_render and tv_weight 0 the equality is exact up to float
// rounding (tests/train/distributed_test.cc checks it).
//
// Rendezvous (`init`): file:///PATH (c10d::FileStore: the ranks of one machine, or a shared
// filesystem; the file must not exist before the run) or tcp://HOST:PORT (c10d::TCPStore: rank 0
// listens on PORT, the others connect to HOST). Backend: gloo (CPU tensors; c10d's
// ProcessGroupGloo) or nccl (CUDA builds of LibTorch with c10d's NCCL backend only).

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <torch/torch.h>

#include "core/train/sample.h"
#include "core/train/trainer.h"

namespace avatar::train {

struct DistributedOptions {
  // Processes in the group (1 = no data parallelism) and this one's rank in [0, world_size).
  int64_t world_size = 1;
  int64_t rank = 0;
  // Rendezvous: file:///PATH or tcp://HOST:PORT.
  std::string init;
  // Collective backend: gloo or nccl.
  std::string backend = "gloo";
  // Seconds to wait for the other ranks (joining, and every collective).
  double timeout_s = 300.0;

  bool enabled() const { return world_size > 1; }
  // Throws InvalidOptions (rank out of range, malformed init URL, unknown backend, nccl in a
  // build without it).
  void Validate() const;
};

// A parsed rendezvous URL.
struct InitMethod {
  std::string scheme;  // "file" or "tcp"
  std::string path;    // file: the store file
  std::string host;    // tcp
  int port = 0;        // tcp
};
// Throws InvalidOptions for anything but file:///PATH and tcp://HOST:PORT (port 1..65535).
InitMethod ParseInitUrl(const std::string& url);

// Whether this build has the NCCL backend (CUDA LibTorch with c10d's NCCL).
bool HaveNccl();

// The trainer's GradientReducer over a c10d process group.
class ProcessGroupReducer : public GradientReducer {
 public:
  // Joins the group; throws Io naming the rendezvous when the other ranks do not join within
  // options.timeout_s, InvalidOptions for invalid options.
  explicit ProcessGroupReducer(const DistributedOptions& options);
  ~ProcessGroupReducer() override;

  int64_t rank() const override { return options_.rank; }
  int64_t world_size() const override { return options_.world_size; }
  bool ReduceGradients(const std::vector<torch::Tensor>& params, bool local_ok, std::vector<double>& values) override;
  void Broadcast(const std::vector<torch::Tensor>& tensors) override;
  void AllMax(std::vector<double>& values) override;
  // Waits until every rank has called it.
  void Barrier();

 private:
  struct Impl;
  DistributedOptions options_;
  std::unique_ptr<Impl> impl_;
};

// Samples [start, start + count) of a batch (views of its tensors).
TrainBatch SliceBatch(const TrainBatch& batch, int64_t start, int64_t count);

// Rank r's shard of every batch of `inner` (which every rank reads in the same order): samples
// r*B/W .. (r+1)*B/W - 1. Next throws InvalidInput when a batch does not divide by W. The cursor
// is the inner source's.
class ShardedBatchSource : public BatchSource {
 public:
  ShardedBatchSource(BatchSource& inner, int64_t rank, int64_t world_size);
  TrainBatch Next() override;
  nlohmann::json State() const override { return inner_.State(); }
  void Restore(const nlohmann::json& state) override { inner_.Restore(state); }

 private:
  BatchSource& inner_;
  int64_t rank_, world_;
};

}  // namespace avatar::train
