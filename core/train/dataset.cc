#include "core/train/dataset.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <numeric>
#include <random>
#include <set>
#include <sstream>

#include <caffe2/serialize/inline_container.h>
#include <caffe2/serialize/read_adapter_interface.h>
#include <nlohmann/json.hpp>
#include <torch/csrc/jit/serialization/import_read.h>
#include <torch/serialize.h>

#include "core/train/shard_check.h"
#include "core/util/error.h"

namespace avatar::train {
namespace {

namespace fs = std::filesystem;

std::vector<char> ReadAll(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Io("cannot read " + path.string() + ": is the dataset built (avatar-studio dataset build)?");
  return std::vector<char>(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// The bytes of a shard for LibTorch's zip reader, never read past their end. LibTorch 1.13's
// torch::pickle_load reads through an adapter without bounds checks, so a shard whose zip records
// point past its end made it read freed memory (found by tests/fuzz, target dataset); here such a
// read comes back short and the zip reader throws c10::Error.
class CheckedShardBytes : public caffe2::serialize::ReadAdapterInterface {
 public:
  explicit CheckedShardBytes(const std::vector<char>& bytes) : bytes_(bytes) {}
  size_t size() const override { return bytes_.size(); }
  size_t read(uint64_t pos, void* buf, size_t n, const char* /*what*/) const override {
    if (pos >= bytes_.size()) return 0;
    const size_t count = static_cast<size_t>(std::min<uint64_t>(n, bytes_.size() - pos));
    std::copy_n(bytes_.data() + pos, count, static_cast<char*>(buf));
    return count;
  }

 private:
  const std::vector<char>& bytes_;
};

// torch::pickle_load (a zip archive holding data.pkl) over CheckedShardBytes, after CheckShard has
// bounded every length that LibTorch would allocate before reading (shard_check.h).
c10::IValue LoadPickledShard(const std::vector<char>& bytes) {
  CheckShard(bytes);
  caffe2::serialize::PyTorchStreamReader reader(std::make_shared<CheckedShardBytes>(bytes));
  return torch::jit::readArchiveAndTensors("data", "", "", c10::nullopt, c10::nullopt, c10::nullopt, reader);
}

// uint8 [...] -> float in [-1,1].
torch::Tensor Signed(const torch::Tensor& u8) { return u8.to(torch::kFloat32).div(127.5).sub(1.0); }
torch::Tensor Unit(const torch::Tensor& u8) { return u8.to(torch::kFloat32).div(255.0); }

}  // namespace

TrainDataset TrainDataset::Open(const std::string& dir, const std::string& split) {
  if (split != "train" && split != "val" && split != "synthetic")
    throw InvalidOptions("split must be train, val or synthetic, got '" + split + "'");
  const fs::path json_path = fs::path(dir) / "dataset.json";
  const std::vector<char> json_bytes = ReadAll(json_path);
  nlohmann::json ds;
  std::string shard_rel;
  TrainDataset out;
  out.split_ = split;
  try {
    ds = nlohmann::json::parse(json_bytes.begin(), json_bytes.end());
    out.image_size_ = ds.at("size").get<int64_t>();
    if (split == "synthetic" && !ds.at("shards").contains("synthetic"))
      throw InvalidInput(json_path.string() +
                         " lists no synthetic pairs: build the dataset with 'avatar-studio dataset build --synthetic N'");
    shard_rel = ds.at("shards").at(split).get<std::string>();
    if (!ds.at("labels").is_array()) throw InvalidInput("labels is not a list");
  } catch (const nlohmann::json::exception& e) {
    throw InvalidInput(json_path.string() + " is corrupted (" + e.what() + "): rebuild the dataset");
  }
  if (out.image_size_ < 8 || out.image_size_ > 4096)
    throw InvalidInput(json_path.string() + " has an invalid size " + std::to_string(out.image_size_));
  const fs::path shard = fs::path(dir) / shard_rel;
  const std::vector<char> bytes = ReadAll(shard);
  auto bad = [&](const std::string& why) {
    return InvalidInput(shard.string() + " is corrupted (" + why + "): rebuild the dataset");
  };
  c10::IValue loaded;
  try {
    loaded = LoadPickledShard(bytes);
  } catch (const c10::Error& e) {
    throw bad(std::string("unreadable: ") + e.what_without_backtrace());
  } catch (const std::exception& e) {
    throw bad(std::string("unreadable: ") + e.what());
  }
  if (!loaded.isGenericDict()) throw bad("not a dict of tensors");
  const c10::impl::GenericDict dict = loaded.toGenericDict();
  auto get = [&](const char* key) {
    auto it = dict.find(c10::IValue(std::string(key)));
    if (it == dict.end() || !it->value().isTensor()) throw bad(std::string("no tensor '") + key + "'");
    const torch::Tensor t = it->value().toTensor();
    // The unpickler takes sizes, strides and offset from the file without checking them against
    // the storage; indexing such a tensor later threw c10::Error (found by tests/fuzz, target
    // dataset). Every element must lie inside the storage.
    if (!t.has_storage() || t.is_sparse() || t.storage_offset() < 0)
      throw bad(std::string("tensor '") + key + "' is malformed");
    uint64_t last = static_cast<uint64_t>(t.storage_offset());
    bool overflow = false;
    for (int64_t d = 0; d < t.dim(); ++d) {
      if (t.size(d) == 0) return t;  // no elements: nothing to read
      if (t.stride(d) < 0) throw bad(std::string("tensor '") + key + "' has a negative stride");
      uint64_t extent = 0;
      overflow |= __builtin_mul_overflow(static_cast<uint64_t>(t.size(d) - 1), static_cast<uint64_t>(t.stride(d)), &extent);
      overflow |= __builtin_add_overflow(last, extent, &last);
    }
    if (overflow || last >= t.storage().nbytes() / t.element_size())
      throw bad(std::string("tensor '") + key + "' reaches past the end of its data");
    return t;
  };
  out.image_ = get("image");
  out.matte_ = get("matte");
  out.eye_mouth_ = get("eye_mouth");
  out.expression_image_ = get("expression_image");
  out.neutral_image_ = get("neutral_image");
  out.neutral_mask_ = get("neutral_mask");
  out.label_ = get("label");
  out.expression_ = get("expression");
  out.identity_ = get("identity");
  out.pairs_ = get("pairs");
  out.pair_kind_ = get("pair_kind");
  const int64_t n = out.image_.dim() == 4 ? out.image_.size(0) : -1;
  const int64_t s = out.image_size_;
  auto check_image = [&](const torch::Tensor& t, int64_t c, const char* name) {
    if (t.scalar_type() != torch::kUInt8 || t.dim() != 4 || t.size(0) != n || t.size(1) != c || t.size(2) != s ||
        t.size(3) != s) {
      std::ostringstream m;
      m << name << " has shape " << t.sizes() << ", expected uint8 [" << n << "," << c << "," << s << "," << s << "]";
      throw bad(m.str());
    }
  };
  if (n < 0) throw bad("image is not [N,3,S,S]");
  // Index and kind tensors are read as int64, labels and coefficients as numbers.
  if (out.identity_.scalar_type() != torch::kInt64 || out.pairs_.scalar_type() != torch::kInt64 ||
      out.pair_kind_.scalar_type() != torch::kInt64)
    throw bad("identity, pairs and pair_kind must be int64");
  if (!out.label_.is_floating_point() || !out.expression_.is_floating_point())
    throw bad("label and expression must be floating point");
  check_image(out.image_, 3, "image");
  check_image(out.matte_, 1, "matte");
  check_image(out.eye_mouth_, 1, "eye_mouth");
  check_image(out.expression_image_, 3, "expression_image");
  check_image(out.neutral_image_, 3, "neutral_image");
  check_image(out.neutral_mask_, 1, "neutral_mask");
  if (out.label_.dim() != 2 || out.label_.size(0) != n || out.label_.size(1) != 25) throw bad("label is not [N,25]");
  if (out.expression_.dim() != 2 || out.expression_.size(0) != n) throw bad("expression is not [N,K]");
  if (out.identity_.dim() != 1 || out.identity_.size(0) != n) throw bad("identity is not [N]");
  if (out.pairs_.dim() != 2 || out.pairs_.size(1) != 2 || out.pair_kind_.dim() != 1 ||
      out.pair_kind_.size(0) != out.pairs_.size(0))
    throw bad("pairs is not [P,2] with pair_kind [P]");
  if (out.pairs_.numel() > 0 && (out.pairs_.min().item<int64_t>() < 0 || out.pairs_.max().item<int64_t>() >= n))
    throw bad("pair index out of range");
  if (!torch::isfinite(out.label_).all().item<bool>()) throw bad("non-finite camera label");
  out.label_ = out.label_.to(torch::kFloat32);
  out.expression_ = out.expression_.to(torch::kFloat32);
  return out;
}

bool TrainDataset::HasSynthetic(const std::string& dir) {
  std::ifstream in(fs::path(dir) / "dataset.json", std::ios::binary);
  if (!in) return false;
  const nlohmann::json ds = nlohmann::json::parse(in, nullptr, false);
  return !ds.is_discarded() && ds.is_object() && ds.contains("shards") && ds["shards"].is_object() &&
         ds["shards"].contains("synthetic");
}

int64_t TrainDataset::CountKind(PairKind kind) const {
  return pair_kind_.eq(static_cast<int64_t>(kind)).sum().item<int64_t>();
}

std::vector<int64_t> TrainDataset::Identities() const {
  std::set<int64_t> ids;
  const auto a = identity_.accessor<int64_t, 1>();
  for (int64_t i = 0; i < a.size(0); ++i) ids.insert(a[i]);
  return {ids.begin(), ids.end()};
}

int64_t TrainDataset::PairIdentity(int64_t index) const {
  if (index < 0 || index >= size())
    throw InvalidInput("pair " + std::to_string(index) + " out of range [0," + std::to_string(size()) + ")");
  return identity_[pairs_[index][0].item<int64_t>()].item<int64_t>();
}

TrainSample TrainDataset::Get(int64_t index) const {
  if (index < 0 || index >= size())
    throw InvalidInput("pair " + std::to_string(index) + " out of range [0," + std::to_string(size()) + ")");
  const int64_t s = pairs_[index][0].item<int64_t>();
  const int64_t t = pairs_[index][1].item<int64_t>();
  auto matted = [&](int64_t i) {
    const torch::Tensor m = Unit(matte_[i]);
    return Signed(image_[i]).mul(m).add(m.sub(1.0));  // black (-1) outside the matte
  };
  TrainSample out;
  out.source = matted(s);
  out.source_matte = Unit(matte_[s]);
  out.source_eye_mouth = Unit(eye_mouth_[s]);
  out.source_label = label_[s].clone();
  out.target = matted(t);
  out.target_matte = Unit(matte_[t]);
  out.target_label = label_[t].clone();
  // I_exp: the source's identity and texture with the target's expression; stored per target
  // frame (identical identity for photo and clip pairs).
  out.expression_image = Signed(expression_image_[t]);
  out.neutral_image = Signed(neutral_image_[s]);
  out.neutral_mask = Unit(neutral_mask_[s]);
  out.target_expression = expression_[t].clone();
  out.kind = static_cast<PairKind>(pair_kind_[index].item<int64_t>());
  out.identity = identity_[s].item<int64_t>();
  return out;
}

void LoaderOptions::Validate() const {
  if (batch_size < 1 || batch_size > 4096) throw InvalidOptions("batch size must be in 1..4096");
  if (!(synthetic_fraction >= 0.0 && synthetic_fraction <= 1.0))
    throw InvalidOptions("the synthetic fraction must be in [0,1]");
}

DataLoader::DataLoader(const TrainDataset& dataset, const LoaderOptions& options)
    : DataLoader(dataset, nullptr, options) {}

DataLoader::DataLoader(const TrainDataset& dataset, const TrainDataset* synthetic, const LoaderOptions& options)
    : dataset_(dataset), synthetic_(synthetic), options_(options) {
  options_.Validate();
  if (options_.synthetic_fraction > 0.0 && (synthetic_ == nullptr || synthetic_->size() == 0))
    throw InvalidOptions("a synthetic fraction > 0 needs synthetic pairs: build the dataset with --synthetic N");
  if (options_.synthetic_fraction > 0.0 && synthetic_->image_size() != dataset.image_size())
    throw InvalidInput("the synthetic pairs are " + std::to_string(synthetic_->image_size()) + " px, the dataset " +
                       std::to_string(dataset.image_size()) + " px");
  if (options_.synthetic_fraction == 0.0) synthetic_ = nullptr;
  if (dataset.size() == 0 && options_.synthetic_fraction < 1.0)
    throw InvalidInput("the " + dataset.split() + " split of the dataset has no pairs");
  StartEpoch(0);
}

void DataLoader::StartEpoch(int64_t epoch) {
  const int64_t real = options_.synthetic_fraction < 1.0 ? dataset_.size() : 0;
  order_.resize(static_cast<size_t>(real));
  std::iota(order_.begin(), order_.end(), 0);
  if (synthetic_ != nullptr) {
    // The epoch's synthetic pairs: successive seeded permutations of the synthetic split, the
    // first continuing where the previous epoch stopped (the count per epoch is fixed).
    const int64_t m = synthetic_->size();
    const double f = options_.synthetic_fraction;
    const int64_t per_epoch =
        f >= 1.0 ? m : std::max<int64_t>(1, static_cast<int64_t>(std::llround(f / (1.0 - f) * real)));
    int64_t first = epoch * per_epoch;
    while (static_cast<int64_t>(order_.size()) < real + per_epoch) {
      const int64_t round = first / m;
      std::vector<int64_t> perm(static_cast<size_t>(m));
      std::iota(perm.begin(), perm.end(), 0);
      std::mt19937_64 prng(options_.seed * 7919ULL + 0x5EEDULL + static_cast<uint64_t>(round));
      std::shuffle(perm.begin(), perm.end(), prng);
      for (int64_t j = first % m; j < m && static_cast<int64_t>(order_.size()) < real + per_epoch; ++j, ++first)
        order_.push_back(dataset_.size() + perm[static_cast<size_t>(j)]);
    }
  }
  if (options_.shuffle) {
    std::mt19937_64 rng(options_.seed * 1000003ULL + static_cast<uint64_t>(epoch));
    std::shuffle(order_.begin(), order_.end(), rng);
  }
  position_ = 0;
}

int64_t DataLoader::BatchesPerEpoch() const {
  const int64_t n = static_cast<int64_t>(order_.size());
  return options_.drop_last ? n / options_.batch_size : (n + options_.batch_size - 1) / options_.batch_size;
}

bool DataLoader::Next(TrainBatch* batch) {
  const size_t remaining = order_.size() - position_;
  if (remaining == 0) return false;
  const size_t take = std::min<size_t>(remaining, static_cast<size_t>(options_.batch_size));
  if (options_.drop_last && take < static_cast<size_t>(options_.batch_size)) {
    position_ = order_.size();
    return false;
  }
  std::vector<TrainSample> samples;
  samples.reserve(take);
  for (size_t i = 0; i < take; ++i) {
    const int64_t k = order_[position_ + i];
    samples.push_back(k < dataset_.size() ? dataset_.Get(k) : synthetic_->Get(k - dataset_.size()));
  }
  position_ += take;
  *batch = Collate(samples);
  return true;
}

}  // namespace avatar::train
