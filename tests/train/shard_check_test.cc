// Shard checks before LibTorch reads a dataset shard (core/train/shard_check.h): real archives
// written by torch::pickle_save pass; lengths that claim more than the file holds (zip records,
// pickled strings, frames, memo indices) are refused without allocating them, and
// TrainDataset::Open turns that into a clean error naming the shard. The defect: a 13 KB shard
// whose pickled key claimed 1.76 GB made LibTorch reserve that much (tests/fuzz, target dataset).

#include <algorithm>
#include <cstring>
#include <functional>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <unistd.h>

#include <gtest/gtest.h>
#include <torch/serialize.h>
#include <torch/torch.h>

#include "core/train/dataset.h"
#include "core/train/shard_check.h"
#include "core/util/error.h"

namespace avatar::train {
namespace {

namespace fs = std::filesystem;

std::vector<char> SmallShard() {
  c10::Dict<std::string, torch::Tensor> dict;
  dict.insert("image", torch::arange(48, torch::kUInt8).reshape({3, 4, 4}));
  dict.insert("labels", torch::linspace(0, 1, 25, torch::kFloat32));
  dict.insert("identity", torch::tensor({7, 9}, torch::kInt64));
  return torch::pickle_save(c10::IValue(dict));
}

// Offset of the first occurrence of `what` in `bytes`.
size_t Find(const std::vector<char>& bytes, const std::string& what) {
  const auto it = std::search(bytes.begin(), bytes.end(), what.begin(), what.end());
  EXPECT_NE(it, bytes.end()) << "'" << what << "' not in the shard";
  return static_cast<size_t>(it - bytes.begin());
}

void PutLe32(std::vector<char>& bytes, size_t at, uint32_t v) {
  for (int i = 0; i < 4; ++i) bytes[at + i] = static_cast<char>((v >> (8 * i)) & 0xFF);
}

std::string ErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "";
}

TEST(ShardCheck, ArchivesWrittenByLibTorchPass) {
  const std::vector<char> bytes = SmallShard();
  const std::vector<ShardRecord> records = CheckShardArchive(bytes);
  bool has_pickle = false;
  for (const ShardRecord& r : records) {
    EXPECT_LE(r.data_offset + r.size, bytes.size()) << r.name;
    has_pickle = has_pickle || r.name.find("data.pkl") != std::string::npos;
  }
  EXPECT_TRUE(has_pickle);
  EXPECT_GE(records.size(), 4u);  // data.pkl, three storages (and the version record)
  EXPECT_NO_THROW(CheckShard(bytes));
}

TEST(ShardCheck, PickledStringClaimingGigabytesIsRefused) {
  std::vector<char> bytes = SmallShard();
  // BINUNICODE 'X', a 4-byte length 5, then "image": the dict key.
  const size_t at = Find(bytes, std::string("X\x05\x00\x00\x00image", 10));
  PutLe32(bytes, at + 1, 1761607686u);
  const std::string why = ErrorOf([&] { CheckShard(bytes); });
  EXPECT_NE(why.find("claims 1761607686 bytes"), std::string::npos) << why;
  EXPECT_NE(why.find("0x58"), std::string::npos) << why;  // names the opcode ('X')
}

TEST(ShardCheck, ZipRecordLargerThanTheFileIsRefused) {
  std::vector<char> bytes = SmallShard();
  // The central-directory entry of data.pkl ("PK\1\2", name length at +28, name at +46);
  // its sizes are at +20 (stored) and +24 (unpacked).
  size_t entry = bytes.size();
  for (size_t at = 0; at + 46 < bytes.size(); ++at) {
    if (std::memcmp(bytes.data() + at, "PK\x01\x02", 4) != 0) continue;
    const size_t len = static_cast<unsigned char>(bytes[at + 28]) | static_cast<unsigned char>(bytes[at + 29]) << 8;
    const std::string name(bytes.data() + at + 46, std::min(len, bytes.size() - at - 46));
    if (name.size() >= 8 && name.compare(name.size() - 8, 8, "data.pkl") == 0) entry = at;
  }
  ASSERT_LT(entry, bytes.size()) << "no directory entry of data.pkl";
  PutLe32(bytes, entry + 20, 0x7FFFFFF0u);
  PutLe32(bytes, entry + 24, 0x7FFFFFF0u);
  const std::string why = ErrorOf([&] { CheckShardArchive(bytes); });
  EXPECT_NE(why.find("claims 2147483632 bytes"), std::string::npos) << why;
}

TEST(ShardCheck, HandMadePicklesAndTheirLengths) {
  auto check = [](const std::string& p) { return ErrorOf([&] { CheckPickleLengths(p.data(), p.size()); }); };
  // PROTO 2, BINUNICODE "ab", STOP.
  EXPECT_EQ(check(std::string("\x80\x02X\x02\x00\x00\x00" "ab.", 10)), "");
  // The same string claiming 2^31 - 1 bytes.
  EXPECT_NE(check(std::string("\x80\x02X\xff\xff\xff\x7f" "ab.", 10)).find("claims 2147483647 bytes"),
            std::string::npos);
  // SHORT_BINUNICODE claiming 200 bytes of 3.
  EXPECT_NE(check(std::string("\x80\x04\x8c\xc8" "ab.", 7)).find("claims 200"), std::string::npos);
  // BINBYTES8 with an 8-byte length of 2^40.
  EXPECT_NE(check(std::string("\x80\x04\x8e\x00\x00\x00\x00\x00\x01\x00\x00.", 13)).find("claims 1099511627776"),
            std::string::npos);
  // FRAME claiming more than follows.
  EXPECT_NE(check(std::string("\x80\x04\x95\x00\x10\x00\x00\x00\x00\x00\x00N.", 13)).find("bytes of frame"),
            std::string::npos);
  // LONG_BINPUT with a memo index of 2^31.
  EXPECT_NE(check(std::string("\x80\x02N\x72\x00\x00\x00\x80.", 9)).find("memo index"), std::string::npos);
  // Protocol 0 text arguments: GLOBAL needs two lines.
  EXPECT_EQ(check("cmodule\nname\n."), "");
  EXPECT_NE(check("cmodule\nname").find("no end of line"), std::string::npos);
  // No STOP, an unknown opcode, a fixed argument cut short.
  EXPECT_NE(check(std::string("\x80\x02N", 3)).find("without its STOP"), std::string::npos);
  EXPECT_NE(check(std::string("\x80\x02\xff.", 4)).find("unknown pickle opcode 0xff"), std::string::npos);
  EXPECT_NE(check(std::string("\x80\x02J\x01\x02", 5)).find("claims 4 bytes"), std::string::npos);
  // Empty input.
  EXPECT_NE(check("").find("without its STOP"), std::string::npos);
}

TEST(ShardCheck, OpenNamesTheShardOfAClaimingString) {
  const fs::path dir = fs::temp_directory_path() / ("shard_check_" + std::to_string(::getpid()));
  fs::create_directories(dir / "shards");
  {
    std::ofstream json(dir / "dataset.json");
    json << R"({"size": 8, "labels": [], "shards": {"train": "shards/train.pt", "val": "shards/val.pt"}})";
  }
  std::vector<char> bytes = SmallShard();
  PutLe32(bytes, Find(bytes, std::string("X\x05\x00\x00\x00image", 10)) + 1, 1761607686u);
  {
    std::ofstream shard(dir / "shards" / "train.pt", std::ios::binary);
    shard.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  }
  try {
    TrainDataset::Open(dir.string(), "train");
    ADD_FAILURE() << "a shard with a string claiming 1.76 GB was accepted";
  } catch (const InvalidInput& e) {
    const std::string why = e.what();
    EXPECT_NE(why.find("train.pt"), std::string::npos) << why;
    EXPECT_NE(why.find("claims 1761607686 bytes"), std::string::npos) << why;
    EXPECT_NE(why.find("rebuild the dataset"), std::string::npos) << why;
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace avatar::train
