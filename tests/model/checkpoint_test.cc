// Checkpoint format: bit-exact round trips and clean errors for damaged or foreign files.

#include <gtest/gtest.h>

#include <fstream>

#include "common/temp_dir.h"
#include "core/io/atomic_file.h"
#include "core/model/checkpoint.h"
#include "core/model/goha_model.h"
#include "core/util/error.h"
#include "model_test_util.h"

namespace avatar {
namespace {

std::string ReadAll(const std::filesystem::path& p) { return ReadFileBytes(p); }
void WriteAll(const std::filesystem::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

template <typename Fn>
std::string ModelLoadMessage(Fn fn) {
  try {
    fn();
  } catch (const ModelLoad& e) {
    return e.what();
  }
  return "<no ModelLoad thrown>";
}

TEST(Checkpoint, RoundTripIsBitExact) {
  avatar::testing::TempDir dir;
  torch::manual_seed(10);
  GohaModel model(avatar::testing::TinyForTest());
  CheckpointInfo info;
  info.step = 1234;
  info.data_provenance = "unit test";
  const auto path = dir.path() / "tiny.ckpt";
  SaveModelCheckpoint(path, model, info);
  std::string fingerprint;
  const LoadedModel loaded = LoadModelCheckpoint(path, &fingerprint);
  EXPECT_EQ(fingerprint.size(), 16u);
  EXPECT_EQ(loaded.info.step, 1234);
  EXPECT_EQ(loaded.info.data_provenance, "unit test");
  EXPECT_EQ(loaded.model->config(), model->config());
  avatar::testing::ExpectBitIdenticalWeights(model, loaded.model);
  // Saving the loaded model again gives the identical file.
  SaveModelCheckpoint(dir.path() / "again.ckpt", const_cast<GohaModel&>(loaded.model), loaded.info);
  EXPECT_EQ(ReadAll(path), ReadAll(dir.path() / "again.ckpt"));
}

TEST(Checkpoint, ArchiveKeepsDtypesAndEmptyTensors) {
  TensorArchive archive;
  archive.kind = "test";
  archive.meta = {{"x", 1}};
  archive.tensors = {{"f64", torch::randn({3, 2}, torch::kFloat64)},
                     {"i64", torch::arange(5)},
                     {"u8", torch::randint(0, 255, {4}, torch::kUInt8)},
                     {"b", torch::tensor({true, false})},
                     {"empty", torch::zeros({0, 3})}};
  const TensorArchive back = DecodeTensorArchive(EncodeTensorArchive(archive), "mem");
  ASSERT_EQ(back.tensors.size(), archive.tensors.size());
  for (size_t i = 0; i < archive.tensors.size(); ++i) {
    EXPECT_EQ(back.tensors[i].first, archive.tensors[i].first);
    EXPECT_TRUE(torch::equal(back.tensors[i].second, archive.tensors[i].second));
    EXPECT_EQ(back.tensors[i].second.scalar_type(), archive.tensors[i].second.scalar_type());
  }
  EXPECT_EQ(back.meta["x"], 1);
}

TEST(Checkpoint, TruncatedFilesFailCleanlyAtEveryLength) {
  avatar::testing::TempDir dir;
  GohaModel model(avatar::testing::TinyForTest());
  const auto path = dir.path() / "m.ckpt";
  SaveModelCheckpoint(path, model, {});
  const std::string bytes = ReadAll(path);
  const auto cut_path = dir.path() / "cut.ckpt";
  for (size_t len : {size_t{0}, size_t{4}, size_t{8}, size_t{12}, size_t{20}, size_t{100}, bytes.size() / 2,
                     bytes.size() - 9, bytes.size() - 1}) {
    WriteAll(cut_path, bytes.substr(0, len));
    const std::string msg = ModelLoadMessage([&] { LoadModelCheckpoint(cut_path); });
    EXPECT_NE(msg.find(cut_path.string()), std::string::npos) << "length " << len << ": " << msg;
    EXPECT_TRUE(msg.find("truncated") != std::string::npos || msg.find("magic") != std::string::npos)
        << "length " << len << ": " << msg;
  }
}

TEST(Checkpoint, CorruptForeignAndMismatchedFilesFailCleanly) {
  avatar::testing::TempDir dir;
  GohaModel model(avatar::testing::TinyForTest());
  const auto path = dir.path() / "m.ckpt";
  SaveModelCheckpoint(path, model, {});
  std::string bytes = ReadAll(path);

  std::string flipped = bytes;
  flipped[bytes.size() / 2] = static_cast<char>(flipped[bytes.size() / 2] ^ 0x40);
  WriteAll(dir.path() / "flip.ckpt", flipped);
  EXPECT_NE(ModelLoadMessage([&] { LoadModelCheckpoint(dir.path() / "flip.ckpt"); }).find("checksum"),
            std::string::npos);

  WriteAll(dir.path() / "png.ckpt", std::string("\x89PNG\r\n\x1a\n0000000000000000", 24));
  EXPECT_NE(ModelLoadMessage([&] { LoadModelCheckpoint(dir.path() / "png.ckpt"); }).find("magic"), std::string::npos);

  std::string newer = bytes;
  newer[8] = 99;  // format version
  WriteAll(dir.path() / "v99.ckpt", newer);
  EXPECT_NE(ModelLoadMessage([&] { LoadModelCheckpoint(dir.path() / "v99.ckpt"); }).find("version"), std::string::npos);

  // An avatar-kind archive is not a model.
  TensorArchive other;
  other.kind = "goha-avatar";
  WriteTensorArchive(dir.path() / "a.ckpt", other);
  EXPECT_NE(ModelLoadMessage([&] { LoadModelCheckpoint(dir.path() / "a.ckpt"); }).find("expected 'goha-model'"),
            std::string::npos);

  // A well-formed archive whose tensor has the wrong shape.
  TensorArchive archive = DecodeTensorArchive(bytes, "m");
  archive.tensors[0].second = torch::zeros({1, 2, 3});
  WriteTensorArchive(dir.path() / "shape.ckpt", archive);
  const std::string msg = ModelLoadMessage([&] { LoadModelCheckpoint(dir.path() / "shape.ckpt"); });
  EXPECT_NE(msg.find(archive.tensors[0].first), std::string::npos) << msg;
  EXPECT_NE(msg.find("expects"), std::string::npos) << msg;

  // Missing tensor.
  archive = DecodeTensorArchive(bytes, "m");
  archive.tensors.pop_back();
  WriteTensorArchive(dir.path() / "missing.ckpt", archive);
  EXPECT_NE(ModelLoadMessage([&] { LoadModelCheckpoint(dir.path() / "missing.ckpt"); }).find("missing"),
            std::string::npos);

  // Missing file: Io, naming the file.
  EXPECT_THROW(LoadModelCheckpoint(dir.path() / "nope.ckpt"), Io);
}

}  // namespace
}  // namespace avatar
