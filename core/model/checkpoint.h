#pragma once
// Versioned tensor archives: model checkpoints (.ckpt) and avatar files (.avatar) share one
// container format, written atomically.
//
// Layout (little-endian):
//   8 bytes  magic "AVSTARCH"
//   u32      format version (kArchiveVersion)
//   u64      header length H, then H bytes of JSON:
//            {"kind": "...", "meta": {...}, "tensors": [{"name", "dtype", "shape", "offset", "nbytes"}]}
//   u64      data length D, then D bytes of raw tensor data (each tensor contiguous, CPU byte order)
//   u64      FNV-1a 64-bit checksum of every byte before it
// Reading checks the magic, version, lengths against the file size, the checksum, that every
// tensor lies inside the data block and that its byte count matches dtype x shape; any failure
// throws ModelLoad naming the file and the reason. Round trips are bit-exact.

#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include <torch/torch.h>
#include <nlohmann/json.hpp>

#include "core/model/model_config.h"

namespace avatar {

inline constexpr uint32_t kArchiveVersion = 1;

struct TensorArchive {
  std::string kind;                                            // e.g. "goha-model", "goha-avatar"
  nlohmann::json meta = nlohmann::json::object();              // free-form metadata
  std::vector<std::pair<std::string, torch::Tensor>> tensors;  // name -> tensor (any device; saved from CPU)

  // The tensor called `name`; throws ModelLoad (mentioning `file`) when absent.
  const torch::Tensor& Get(const std::string& name, const std::string& file = {}) const;
};

// Serialises / parses the archive bytes. Supported dtypes: float32, float64, float16, int64, int32, uint8, bool.
std::string EncodeTensorArchive(const TensorArchive& archive);
// `source` names the file in error messages. Throws ModelLoad.
TensorArchive DecodeTensorArchive(const std::string& bytes, const std::string& source);

// Atomic write (Io on failure) and read (Io when missing, ModelLoad when malformed). `expected_kind`
// non-empty: a different kind throws ModelLoad ("this is a ... file, expected ...").
void WriteTensorArchive(const std::filesystem::path& path, const TensorArchive& archive);
// `fingerprint` (optional) receives the stored checksum as 16 hex digits.
TensorArchive ReadTensorArchive(const std::filesystem::path& path, const std::string& expected_kind = {},
                                std::string* fingerprint = nullptr);

// Metadata stored with every model checkpoint.
struct CheckpointInfo {
  int64_t step = 0;             // training step the weights come from (0 = random init)
  std::string data_provenance;  // what the weights were trained on ("random init" for none)
  std::string created_by;       // program and version
  // Whether the super-resolution module was trained (stage II). Stage-I weights leave it at its
  // initialisation; renderers then upsample the raw render instead of running it. Files written
  // before this field existed read as false.
  bool sr_trained = false;
};

}  // namespace avatar
