// The bad-input corpus (issue 16): damaged, hostile and out-of-range inputs driven through the
// real avatar-studio executable over every command. Every file is made here, at test time, in a
// temporary folder (no third-party faces are committed): truncated and garbage images, zero-byte
// files, headers that claim 30000x30000 pixels, CMYK / 16-bit / alpha / grey images, videos with
// no frames, one frame or a variable frame rate, JSON with wrong types or non-finite numbers
// (keyframes, model configs, dataset.json), truncated or garbage checkpoints and avatar files, and
// out-of-range options.
//
// Each case runs under a timeout in an empty working folder and must end with the documented exit
// code (1 for a bad file, 2 for a bad option; README "Exit codes"), a message naming the file or
// flag, no "internal error", and nothing written: the output folder stays empty and the input
// folder keeps exactly its files. A few inputs are valid but unusual (CMYK, 16-bit, alpha, grey,
// one-frame and variable-rate videos): those must be accepted, with the result checked.
#include <unistd.h>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include <algorithm>
#include <cctype>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <map>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "common/run_process.h"
#include "common/temp_dir.h"
#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/io/video_io.h"
#include "core/model/goha_model.h"

namespace avatar {
namespace {

namespace fs = std::filesystem;
using avatar::testing::ProcessResult;
using avatar::testing::TempDir;

// Seconds one case may run before it counts as a hang.
constexpr int kCaseTimeoutSeconds = 180;

// ---------------------------------------------------------------------------------------------
// Byte-level helpers for hand-made files.

std::string Bytes(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void Put(const fs::path& file, const std::string& bytes) {
  std::ofstream out(file, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  ASSERT_TRUE(out.good()) << "cannot write the corpus file " << file;
}

std::string Encode(const std::string& ext, const cv::Mat& image, const std::vector<int>& params = {}) {
  std::vector<uchar> buffer;
  EXPECT_TRUE(cv::imencode(ext, image, buffer, params)) << ext;
  return std::string(buffer.begin(), buffer.end());
}

std::string Le16(uint32_t v) { return std::string{char(v & 0xFF), char((v >> 8) & 0xFF)}; }
std::string Le32(uint32_t v) { return Le16(v & 0xFFFF) + Le16(v >> 16); }
std::string Be32(uint32_t v) {
  return std::string{char((v >> 24) & 0xFF), char((v >> 16) & 0xFF), char((v >> 8) & 0xFF), char(v & 0xFF)};
}

uint32_t Crc32(const std::string& data) {
  uint32_t crc = 0xFFFFFFFFu;
  for (unsigned char byte : data) {
    crc ^= byte;
    for (int k = 0; k < 8; ++k) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
  }
  return ~crc;
}

// A PNG chunk with its length and CRC.
std::string PngChunk(const std::string& type, const std::string& data) {
  return Be32(static_cast<uint32_t>(data.size())) + type + data + Be32(Crc32(type + data));
}

// Random noise (no face), deterministic.
cv::Mat Noise(int width, int height, int type = CV_8UC3, uint64_t seed = 7) {
  cv::Mat m(height, width, type);
  cv::RNG rng(seed);
  rng.fill(m, cv::RNG::UNIFORM, 0, CV_MAT_DEPTH(type) == CV_16U ? 65535 : 255);
  return m;
}

// A smooth synthetic picture (no face): gradients and a disk.
cv::Mat Picture(int width, int height) {
  cv::Mat m(height, width, CV_8UC3);
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) m.at<cv::Vec3b>(y, x) = cv::Vec3b(x * 255 / width, y * 255 / height, 128);
  cv::circle(m, cv::Point(width / 2, height / 2), std::min(width, height) / 4, cv::Scalar(40, 180, 220), cv::FILLED);
  return m;
}

// A little-endian baseline TIFF: one strip, uncompressed, `samples` 8-bit channels.
std::string Tiff(uint32_t width, uint32_t height, int samples, int photometric, const std::string& pixels) {
  struct Entry {
    uint16_t tag, type;
    uint32_t count, value;
  };
  const uint32_t ifd = 8;
  const int entries = samples == 4 ? 10 : 9;
  const uint32_t after_ifd = ifd + 2 + 12 * entries + 4;
  const uint32_t bits_at = after_ifd;  // `samples` SHORTs when samples > 2
  const uint32_t data_at = bits_at + 2 * samples + (samples % 2 ? 2 : 0);
  std::vector<Entry> e = {{256, 4, 1, width},
                          {257, 4, 1, height},
                          {258, 3, static_cast<uint32_t>(samples), samples > 2 ? bits_at : 8u},
                          {259, 3, 1, 1},
                          {262, 3, 1, static_cast<uint32_t>(photometric)},
                          {273, 4, 1, data_at},
                          {277, 3, 1, static_cast<uint32_t>(samples)},
                          {278, 4, 1, height},
                          {279, 4, 1, static_cast<uint32_t>(pixels.size())}};
  if (samples == 4) e.push_back({332, 3, 1, 1});  // InkSet: CMYK.
  std::string b = "II" + Le16(42) + Le32(ifd) + Le16(static_cast<uint32_t>(e.size()));
  for (const Entry& x : e) {
    b += Le16(x.tag) + Le16(x.type) + Le32(x.count);
    b += x.type == 3 && x.count == 1 ? Le16(x.value) + Le16(0) : Le32(x.value);
  }
  b += Le32(0);
  for (int s = 0; s < samples && samples > 2; ++s) b += Le16(8);
  if (samples > 2 && samples % 2) b += Le16(0);
  b.resize(data_at, '\0');
  return b + pixels;
}

// ---------------------------------------------------------------------------------------------
// The corpus: every file by name, made on first use in the case's input folder.

class Corpus {
 public:
  explicit Corpus(fs::path dir) : dir_(std::move(dir)) {}

  fs::path Get(const std::string& name) {
    const fs::path path = dir_ / name;
    if (made_.insert(name).second) Make(name, path);
    return path;
  }
  static std::string Portrait() {
    return DataPaths::Resolve().Require(DataPaths::kDefaultPortrait, "the sample portrait (run scripts/setup)").string();
  }

 private:
  // A valid file to cut or damage.
  std::string Valid(const std::string& kind) {
    if (kind == "png") return Encode(".png", Picture(64, 48));
    if (kind == "jpg") return Encode(".jpg", Picture(64, 48));
    if (kind == "mp4") return Bytes(Get("valid.mp4"));
    if (kind == "ckpt") return Bytes(Get("valid.ckpt"));
    if (kind == "avatar") return Bytes(Get("valid.avatar"));
    ADD_FAILURE() << "no valid " << kind;
    return {};
  }

  static std::string Garbage(size_t n, uint32_t seed) {
    std::mt19937 rng(seed);
    std::string s(n, '\0');
    for (auto& c : s) c = static_cast<char>(rng() & 0xFF);
    return s;
  }

  // Flips a run of bytes in the middle of a valid file.
  static std::string Damaged(std::string bytes) {
    for (size_t i = bytes.size() / 2; i < bytes.size() / 2 + 64 && i < bytes.size(); ++i) bytes[i] = char(~bytes[i]);
    return bytes;
  }

  void Ffmpeg(const std::vector<std::string>& args) {
    std::vector<std::string> all = {"-nostdin", "-y", "-v", "error"};
    all.insert(all.end(), args.begin(), args.end());
    ASSERT_EQ(RunProgram("ffmpeg", all), 0) << "ffmpeg could not make a corpus video";
  }

  // A dataset folder: dataset.json with `json` (empty = none) and shards/train.pt with `shard`.
  void Dataset(const fs::path& dir, const std::string& json, const std::string& shard = "") {
    fs::create_directories(dir / "shards");
    if (!json.empty()) Put(dir / "dataset.json", json);
    if (!shard.empty()) Put(dir / "shards" / "train.pt", shard);
  }

  static std::string DatasetJson(const std::string& size, const std::string& labels = "[]") {
    return R"({"size": )" + size + R"(, "labels": )" + labels +
           R"(, "shards": {"train": "shards/train.pt", "val": "shards/val.pt"}, "records": "records.json",
              "pairs": "pairs.json", "counts": {"faces": 1}, "split": {"seed": 1, "train": ["a"], "val": ["b"]}})";
  }

  void Make(const std::string& name, const fs::path& p) {
    // --- images
    if (name == "empty.png" || name == "empty.jpg" || name == "empty.mp4" || name == "empty.json" ||
        name == "empty.ckpt" || name == "empty.avatar" || name == "empty_config.json") {
      Put(p, "");
    } else if (name == "garbage.png" || name == "garbage.jpg" || name == "garbage.webp" || name == "garbage.tif" ||
               name == "garbage.bmp") {
      Put(p, Garbage(5000, 1));
    } else if (name == "text.jpg") {
      Put(p, "this is not a picture\n");
    } else if (name == "truncated.png") {
      const std::string v = Valid("png");
      Put(p, v.substr(0, v.size() / 2));
    } else if (name == "truncated.jpg") {
      const std::string v = Valid("jpg");
      Put(p, v.substr(0, v.size() / 2));
    } else if (name == "header_only.png") {
      Put(p, Valid("png").substr(0, 33));
    } else if (name == "signature_only.png") {
      Put(p, Valid("png").substr(0, 8));
    } else if (name == "damaged.png") {
      Put(p, Damaged(Valid("png")));
    } else if (name == "damaged.jpg") {
      Put(p, Damaged(Valid("jpg")));
    } else if (name == "huge.png" || name == "zero_size.png" || name == "huge_wide.png") {
      const uint32_t w = name == "zero_size.png" ? 0 : name == "huge_wide.png" ? 200000 : 30000;
      const uint32_t h = name == "zero_size.png" ? 0 : name == "huge_wide.png" ? 2 : 30000;
      std::string ihdr = Be32(w) + Be32(h) + std::string{8, 2, 0, 0, 0};
      Put(p, std::string("\x89PNG\r\n\x1a\n", 8) + PngChunk("IHDR", ihdr) + PngChunk("IDAT", std::string(20, 'x')) +
                 PngChunk("IEND", ""));
    } else if (name == "huge.jpg") {
      std::string v = Valid("jpg");
      const size_t sof = v.find("\xFF\xC0");
      ASSERT_NE(sof, std::string::npos);
      v[sof + 5] = v[sof + 7] = char(0x75);  // 30000 = 0x7530
      v[sof + 6] = v[sof + 8] = char(0x30);
      Put(p, v);
    } else if (name == "huge.bmp") {
      std::string b = "BM" + Le32(54 + 300) + Le32(0) + Le32(54) + Le32(40) + Le32(30000) + Le32(30000) + Le16(1) +
                      Le16(24) + Le32(0) + Le32(0) + Le32(2835) + Le32(2835) + Le32(0) + Le32(0);
      Put(p, b + std::string(300, '\x40'));
    } else if (name == "huge.tif") {
      Put(p, Tiff(30000, 30000, 3, 2, std::string(300, '\x40')));
    } else if (name == "huge.ppm") {
      Put(p, "P6\n30000 30000\n255\n" + std::string(300, '\x40'));
    } else if (name == "huge.webp") {
      // VP8X header only: a 30000x30000 canvas and no image data.
      const uint32_t w = 30000 - 1, h = 30000 - 1;
      std::string vp8x = std::string{0, 0, 0, 0} + std::string{char(w & 0xFF), char((w >> 8) & 0xFF), char(w >> 16)} +
                         std::string{char(h & 0xFF), char((h >> 8) & 0xFF), char(h >> 16)};
      const std::string body = "WEBP" + std::string("VP8X") + Le32(10) + vp8x;
      Put(p, "RIFF" + Le32(static_cast<uint32_t>(body.size())) + body);
    } else if (name == "mp4_named.jpg") {
      Put(p, Valid("mp4"));
    } else if (name == "gif.gif") {
      Put(p, std::string("GIF89a") + Le16(10) + Le16(10) + std::string{0, 0, 0} + ";");
    } else if (name == "svg.png") {
      Put(p, "<svg xmlns='http://www.w3.org/2000/svg' width='10' height='10'/>");
    } else if (name == "folder.jpg" || name == "folder.mp4") {
      fs::create_directories(p);
    } else if (name == "cmyk.tif") {
      std::string pixels;
      for (int i = 0; i < 64 * 48; ++i) pixels += std::string{char(i % 200), char(60), char(120), char(10)};
      Put(p, Tiff(64, 48, 4, 5, pixels));
    } else if (name == "rgb16.png") {
      Put(p, Encode(".png", Noise(64, 48, CV_16UC3)));
    } else if (name == "grey16.png") {
      Put(p, Encode(".png", Noise(64, 48, CV_16UC1)));
    } else if (name == "rgba.png") {
      Put(p, Encode(".png", Noise(64, 48, CV_8UC4)));
    } else if (name == "grey.png") {
      Put(p, Encode(".png", Noise(64, 48, CV_8UC1)));
    } else if (name == "rgb16.tif") {
      Put(p, Encode(".tiff", Noise(64, 48, CV_16UC3)));
    } else if (name == "grey.jpg") {
      cv::Mat grey;
      cv::cvtColor(Picture(64, 48), grey, cv::COLOR_BGR2GRAY);
      Put(p, Encode(".jpg", grey));
    } else if (name == "one_pixel.png") {
      Put(p, Encode(".png", Noise(1, 1)));
    } else if (name == "strip.png") {
      Put(p, Encode(".png", Noise(4000, 2)));
    } else if (name == "no_face.png") {
      Put(p, Encode(".png", Picture(320, 240)));
    } else if (name == "no_face.jpg") {
      Put(p, Encode(".jpg", Picture(320, 240)));
      // --- videos
    } else if (name == "valid.mp4") {
      Ffmpeg({"-f", "lavfi", "-i", "testsrc=size=64x64:rate=10", "-t", "1", "-c:v", "libx264", "-pix_fmt", "yuv420p",
              p.string()});
    } else if (name == "garbage.mp4" || name == "garbage.mov") {
      Put(p, Garbage(20000, 2));
    } else if (name == "text.avi") {
      Put(p, "RIFF....AVI not really\n");
    } else if (name == "truncated.mp4") {
      Put(p, Valid("mp4").substr(0, 1500));
    } else if (name == "damaged.mp4") {
      Put(p, Damaged(Valid("mp4")));
    } else if (name == "audio_only.mp4") {
      Ffmpeg({"-f", "lavfi", "-i", "sine=frequency=440:duration=1", "-c:a", "aac", p.string()});
    } else if (name == "no_frames.mp4") {
      Ffmpeg({"-f", "lavfi", "-i", "testsrc=size=64x64:rate=10", "-frames:v", "0", "-c:v", "libx264", p.string()});
    } else if (name == "one_frame.mp4") {
      cv::VideoWriter w(p.string(), cv::CAP_FFMPEG, cv::VideoWriter::fourcc('a', 'v', 'c', '1'), 25.0, cv::Size(64, 64));
      ASSERT_TRUE(w.isOpened()) << "OpenCV cannot write MP4 here";
      w.write(Picture(64, 64));
      w.release();
    } else if (name == "vfr.mp4") {
      // Frame n shown at n^2/50 s: every interval is longer than the one before.
      Ffmpeg({"-f", "lavfi", "-i", "testsrc=size=64x64:rate=10", "-frames:v", "12", "-vf", "setpts=N*N/50/TB",
              "-fps_mode", "vfr", "-c:v", "libx264", "-pix_fmt", "yuv420p", p.string()});
    } else if (name == "tiny_frames.mp4") {
      Ffmpeg({"-f", "lavfi", "-i", "testsrc=size=2x2:rate=5", "-t", "1", "-c:v", "mpeg4", p.string()});
      // --- keyframes
    } else if (name == "keys_garbage.json") {
      Put(p, Garbage(300, 3));
    } else if (name == "keys_deep.json") {
      Put(p, "{\"keys\": " + std::string(200000, '[') + std::string(200000, ']') + "}");
    } else if (name.rfind("keys_", 0) == 0) {
      static const std::map<std::string, std::string> keys = {
          {"keys_truncated.json", R"({"fps": 10, "keys": [{"time": 0, "yaw": )"},
          {"keys_array.json", R"([1, 2, 3])"},
          {"keys_no_keys.json", R"({"fps": 10})"},
          {"keys_empty.json", R"({"keys": []})"},
          {"keys_not_list.json", R"({"keys": {"time": 0}})"},
          {"keys_key_number.json", R"({"keys": [5]})"},
          {"keys_time_string.json", R"({"keys": [{"time": "zero"}]})"},
          {"keys_nan.json", R"({"keys": [{"time": 0, "yaw": NaN}]})"},
          {"keys_infinite.json", R"({"keys": [{"time": 0, "yaw": 1e999}]})"},
          {"keys_fps_zero.json", R"({"fps": 0, "keys": [{"time": 0}]})"},
          {"keys_fps_string.json", R"({"fps": "fast", "keys": [{"time": 0}]})"},
          {"keys_fps_huge.json", R"({"fps": 1e9, "keys": [{"time": 0}]})"},
          {"keys_negative_time.json", R"({"keys": [{"time": -1}]})"},
          {"keys_zoom_zero.json", R"({"keys": [{"time": 0, "zoom": 0}]})"},
          {"keys_duration_huge.json", R"({"duration": 1e12, "keys": [{"time": 0}]})"},
          {"keys_expression_list.json", R"({"keys": [{"time": 0, "expression": [1, 2]}]})"},
          {"keys_expression_string.json", R"({"keys": [{"time": 0, "expression": {"smile": "big"}}]})"},
          {"keys_expression_overflow.json", R"({"keys": [{"time": 0, "expression": {"smile": 1e300}}]})"},
          {"keys_unknown_control.json", R"({"keys": [{"time": 0, "expression": {"no_such_control": 1}}]})"},
          {"keys_bad_utf8.json", "{\"keys\": [{\"time\": 0, \"expression\": {\"\xff\xfe\": 1}}]}"},
      };
      auto it = keys.find(name);
      ASSERT_NE(it, keys.end()) << name;
      Put(p, it->second);
      // --- model configs (train --config FILE)
    } else if (name.rfind("config_", 0) == 0) {
      static const std::map<std::string, std::string> configs = {
          {"config_garbage.json", "{{{{ not json"},
          {"config_array.json", "[1, 2]"},
          {"config_wrong_type.json", R"({"image_size": "big"})"},
          {"config_nan.json", R"({"image_size": NaN})"},
          {"config_infinite.json", R"({"image_size": 1e999})"},
          {"config_negative.json", R"({"image_size": -64})"},
          {"config_huge.json", R"({"image_size": 1000000000})"},
          {"config_fraction.json", R"({"image_size": 64.5})"},
          {"config_unknown.json", R"({"no_such_field": 1})"},
          {"config_null.json", R"({"image_size": null})"},
      };
      auto it = configs.find(name);
      ASSERT_NE(it, configs.end()) << name;
      Put(p, it->second);
      // --- checkpoints and avatar files
    } else if (name == "valid.ckpt") {
      torch::manual_seed(1);
      GohaModel model(ModelConfig::Tiny());
      CheckpointInfo info;
      info.data_provenance = "random init (bad-input corpus)";
      SaveModelCheckpoint(p, model, info);
    } else if (name == "valid.avatar") {
      const std::string cmd = std::string("'") + AVATAR_STUDIO_EXE + "' reconstruct '" + Portrait() +
                              "' --random-weights --config tiny -o '" + p.string() + "'";
      const ProcessResult r = avatar::testing::RunProcess(cmd, "env -u DISPLAY AVATAR_THREADS=2");
      ASSERT_EQ(r.exit_code, 0) << "cannot make the valid avatar file\n" << r.out << r.err;
    } else if (name == "garbage.ckpt" || name == "garbage.avatar") {
      Put(p, Garbage(100000, 4));
    } else if (name == "truncated.ckpt") {
      const std::string v = Valid("ckpt");
      Put(p, v.substr(0, v.size() / 2));
    } else if (name == "header_only.ckpt") {
      Put(p, Valid("ckpt").substr(0, 64));
    } else if (name == "damaged.ckpt") {
      Put(p, Damaged(Valid("ckpt")));
    } else if (name == "json.ckpt") {
      Put(p, R"({"config": "tiny", "weights": []})");
    } else if (name == "png.ckpt") {
      Put(p, Valid("png"));
    } else if (name == "truncated.avatar") {
      const std::string v = Valid("avatar");
      Put(p, v.substr(0, v.size() / 2));
    } else if (name == "header_only.avatar") {
      Put(p, Valid("avatar").substr(0, 64));
    } else if (name == "damaged.avatar") {
      Put(p, Damaged(Valid("avatar")));
    } else if (name == "ckpt_named.avatar") {
      Put(p, Valid("ckpt"));
      // --- dataset folders (dataset inspect, train, eval)
    } else if (name == "ds_no_json") {
      Dataset(p, "");
    } else if (name == "ds_empty_json") {
      fs::create_directories(p);
      Put(p / "dataset.json", "");
    } else if (name == "ds_garbage_json") {
      Dataset(p, Garbage(400, 5));
    } else if (name == "ds_array_json") {
      Dataset(p, "[1, 2, 3]");
    } else if (name == "ds_size_string") {
      Dataset(p, DatasetJson("\"big\""));
    } else if (name == "ds_size_nan") {
      Dataset(p, DatasetJson("NaN"));
    } else if (name == "ds_size_huge") {
      Dataset(p, DatasetJson("1000000"), Garbage(1000, 6));
    } else if (name == "ds_labels_nan") {
      Dataset(p, DatasetJson("128", R"([["a.png", [NaN]]])"));
    } else if (name == "ds_garbage_shard") {
      Dataset(p, DatasetJson("128"), Garbage(5000, 7));
    } else if (name == "ds_no_shard") {
      Dataset(p, DatasetJson("128"));
    } else if (name == "ds_png_shard") {
      Dataset(p, DatasetJson("128"), Valid("png"));
    } else if (name == "ds_wrong_types") {
      // Valid JSON, every field of the wrong type, and records/pairs that are not lists.
      Dataset(p, R"({"size": 128, "labels": "none", "shards": {"train": 5}, "records": 3, "pairs": [],
                      "counts": "many", "split": "none"})");
      Put(p / "records.json", R"({"pose": "front"})");
    } else if (name == "ds_records_bad") {
      Dataset(p, DatasetJson("128"), Garbage(100, 8));
      Put(p / "records.json", R"([{"pose": {"yaw": "left"}, "beta": [1]}])");
      Put(p / "pairs.json", R"([{"kind": "clip", "d_yaw": null}])");
    } else {
      ADD_FAILURE() << "no corpus file '" << name << "'";
    }
  }

  fs::path dir_;
  std::set<std::string> made_;
};

// ---------------------------------------------------------------------------------------------
// Cases.

struct Case {
  std::string name;
  // Arguments with placeholders: {in:NAME} (a corpus file), {out:NAME} (a path in the output
  // folder), {portrait} (the sample portrait).
  std::string args;
  // Exit code: 1 error (a bad file), 2 usage error (a bad option), 0 accepted.
  int exit_code;
  // Words the message must contain besides the names of the corpus files used.
  std::vector<std::string> words = {};
  // Accepted cases: entries the output folder must then hold, and words stdout must contain.
  std::vector<std::string> written = {};
};

// gtest prints a failing parameter with this (the name, not the struct's bytes).
void PrintTo(const Case& c, std::ostream* os) { *os << c.name << ": avatar-studio " << c.args; }

const char* const kView = "view {in:X} -o {out:view.png}";
const char* const kReconstruct = "reconstruct {in:X} --random-weights --config tiny -o {out:a.avatar}";

// Expands one template over a list of input files.
std::vector<Case> Over(const std::string& prefix, const std::string& tmpl, const std::vector<std::string>& inputs,
                       int exit_code, const std::vector<std::string>& words = {}) {
  std::vector<Case> cases;
  for (const auto& input : inputs) {
    std::string args = tmpl;
    args.replace(args.find("{in:X}"), 6, "{in:" + input + "}");
    std::string id = prefix + "_" + input;
    std::replace_if(id.begin(), id.end(), [](char c) { return !std::isalnum(static_cast<unsigned char>(c)); }, '_');
    cases.push_back({id, args, exit_code, words});
  }
  return cases;
}

std::vector<Case> AllCases() {
  std::vector<Case> all;
  auto add = [&](std::vector<Case> more) { all.insert(all.end(), more.begin(), more.end()); };
  const std::vector<std::string> bad_images = {
      "empty.png",     "empty.jpg",      "garbage.png",  "garbage.jpg",        "garbage.webp", "garbage.tif",
      "garbage.bmp",   "text.jpg",       "truncated.png", "truncated.jpg",     "header_only.png",
      "signature_only.png", "damaged.png", "damaged.jpg", "huge.png",          "huge_wide.png", "zero_size.png",
      "huge.jpg",      "huge.bmp",       "huge.tif",     "huge.ppm",           "huge.webp",    "mp4_named.jpg",
      "gif.gif",       "svg.png",        "folder.jpg"};
  // Every bad image through the studio's loader (view); the hostile headers through every
  // command that reads a photo.
  add(Over("view", kView, bad_images, 1));
  const std::vector<std::string> hostile = {"empty.jpg", "truncated.jpg", "huge.png", "huge.bmp", "damaged.png"};
  add(Over("analyze", "analyze {in:X} -o {out:analysis}", hostile, 1));
  add(Over("fit", "fit {in:X} -o {out:fit}", hostile, 1));
  add(Over("reconstruct", kReconstruct, hostile, 1));
  add(Over("animate_portrait",
           "animate {in:X} --renderer morphable --view orbit --seconds 0.4 --fps 5 --width 64 --height 64 "
           "-o {out:clip.mp4}",
           {"empty.png", "huge.tif", "garbage.jpg"}, 1));
  all.push_back({"view_missing_file", "view {missing} -o {out:view.png}", 1, {"missing.jpg", "check the path"}});

  // Valid but unusual images: the studio's loader accepts them (8-bit BGR of the right size),
  // and face analysis refuses them cleanly (no face in a generated picture).
  for (const char* image : {"cmyk.tif", "rgb16.png", "grey16.png", "rgba.png", "grey.png", "rgb16.tif", "grey.jpg"}) {
    std::string id = std::string("view_accepts_") + image;
    std::replace(id.begin(), id.end(), '.', '_');
    all.push_back({id, "view {in:" + std::string(image) + "} --width 80 --height 60 -o {out:view.png}", 0, {}, {"view.png"}});
  }
  add(Over("reconstruct_no_face", kReconstruct, {"cmyk.tif", "rgb16.png", "rgba.png", "grey.png", "no_face.jpg"}, 1,
           {"face"}));
  add(Over("analyze_no_face", "analyze {in:X} -o {out:analysis}", {"one_pixel.png", "strip.png", "no_face.png"}, 1));
  add(Over("fit_no_face", "fit {in:X} -o {out:fit}", {"grey16.png"}, 1, {"face"}));

  // Videos: as the analysed clip and as the driver.
  const std::vector<std::string> bad_videos = {"empty.mp4",    "garbage.mp4", "garbage.mov",    "text.avi",
                                               "truncated.mp4", "audio_only.mp4", "no_frames.mp4", "folder.mp4"};
  add(Over("analyze_video", "analyze {in:X} --json", bad_videos, 1));
  add(Over("animate_driver",
           "animate {portrait} {in:X} --renderer morphable --width 64 --height 64 -o {out:clip.mp4}",
           {"empty.mp4", "garbage.mp4", "truncated.mp4", "audio_only.mp4", "no_frames.mp4", "text.avi"}, 1));
  all.push_back({"animate_driver_image", "animate {portrait} {in:no_face.png} --renderer morphable -o {out:clip.mp4}", 1,
                 {"neither a video"}});
  // One frame, a variable frame rate, 2x2 frames: analysed without error (no face in them).
  all.push_back({"analyze_video_one_frame", "analyze {in:one_frame.mp4}", 0, {"0 of 1 frames"}});
  all.push_back({"analyze_video_vfr", "analyze {in:vfr.mp4}", 0, {"0 of 12 frames"}});
  all.push_back({"analyze_video_tiny_frames", "analyze {in:tiny_frames.mp4}", 0, {"0 of 5 frames"}});
  all.push_back({"analyze_video_damaged", "analyze {in:damaged.mp4}", 0, {"frames of"}});

  // Keyframes.
  const std::vector<std::string> bad_keys = {
      "empty.json",           "keys_garbage.json",     "keys_truncated.json",     "keys_array.json",
      "keys_no_keys.json",    "keys_empty.json",       "keys_not_list.json",      "keys_key_number.json",
      "keys_time_string.json", "keys_nan.json",        "keys_infinite.json",      "keys_fps_zero.json",
      "keys_fps_string.json", "keys_fps_huge.json",    "keys_negative_time.json", "keys_zoom_zero.json",
      "keys_duration_huge.json", "keys_expression_list.json", "keys_expression_string.json",
      "keys_expression_overflow.json", "keys_unknown_control.json", "keys_bad_utf8.json", "keys_deep.json"};
  add(Over("animate_keys", "animate {portrait} {in:X} --renderer morphable --width 64 --height 64 -o {out:frames}",
           bad_keys, 1));

  // Checkpoints and avatar files.
  const std::vector<std::string> bad_ckpts = {"empty.ckpt",  "garbage.ckpt", "truncated.ckpt", "header_only.ckpt",
                                              "damaged.ckpt", "json.ckpt",   "png.ckpt"};
  add(Over("reconstruct_checkpoint", "reconstruct {portrait} --checkpoint {in:X} -o {out:a.avatar}", bad_ckpts, 1));
  add(Over("render_checkpoint", "render {in:valid.avatar} --checkpoint {in:X} -o {out:r.png}",
           {"garbage.ckpt", "truncated.ckpt"}, 1));
  add(Over("eval_checkpoint", "eval --checkpoint {in:X} --data {in:ds_garbage_shard} --out {out:eval}",
           {"empty.ckpt", "truncated.ckpt", "garbage.ckpt"}, 1));
  add(Over("animate_checkpoint",
           "animate {portrait} --checkpoint {in:X} --view orbit --seconds 0.4 --fps 5 --width 64 --height 64 "
           "-o {out:clip.mp4}",
           {"truncated.ckpt"}, 1));
  const std::vector<std::string> bad_avatars = {"empty.avatar",   "garbage.avatar",     "truncated.avatar",
                                                "header_only.avatar", "damaged.avatar", "ckpt_named.avatar",
                                                "folder.jpg"};
  add(Over("render_avatar", "render {in:X} --random-weights -o {out:r.png}", bad_avatars, 1));

  // Model configs (train --config FILE): a bad config file is a bad option value.
  const std::vector<std::string> bad_configs = {
      "empty_config.json",   "config_garbage.json",  "config_array.json",    "config_wrong_type.json",
      "config_nan.json",     "config_infinite.json", "config_negative.json", "config_huge.json",
      "config_fraction.json", "config_unknown.json", "config_null.json"};
  add(Over("train_config", "train --config {in:X} --data {in:ds_garbage_shard} --out {out:run} --steps 1", bad_configs, 2));

  // Datasets.
  const std::vector<std::string> bad_datasets = {"ds_no_json",   "ds_empty_json", "ds_garbage_json",  "ds_array_json",
                                                 "ds_size_string", "ds_size_nan", "ds_size_huge",     "ds_labels_nan",
                                                 "ds_garbage_shard", "ds_no_shard", "ds_png_shard",  "ds_wrong_types"};
  add(Over("train_data", "train --config tiny --data {in:X} --out {out:run} --steps 1 --perceptual none", bad_datasets, 1));
  add(Over("dataset_inspect", "dataset inspect {in:X}",
           {"ds_no_json", "ds_garbage_json", "ds_wrong_types", "ds_records_bad", "ds_garbage_shard"}, 1));
  add(Over("eval_data", "eval --checkpoint {in:valid.ckpt} --data {in:X} --out {out:eval}",
           {"ds_no_json", "ds_garbage_json", "ds_garbage_shard", "ds_size_huge"}, 1));

  // Out-of-range options: usage errors naming the flag.
  const std::vector<Case> options = {
      {"opt_view_width_zero", "view {in:no_face.png} --width 0 -o {out:v.png}", 2, {"--width"}},
      {"opt_view_height_huge", "view {in:no_face.png} --height 1000000 -o {out:v.png}", 2, {"--height"}},
      {"opt_view_width_text", "view {in:no_face.png} --width wide -o {out:v.png}", 2, {"--width"}},
      {"opt_threads_negative", "view {in:no_face.png} --threads -3 -o {out:v.png}", 2, {"--threads"}},
      {"opt_analyze_max_frames", "analyze {in:valid.mp4} --max-frames -1", 2, {"--max-frames"}},
      {"opt_fit_size", "fit {in:no_face.png} --size 5 -o {out:fit}", 2, {"--size"}},
      {"opt_fit_supersample", "fit {in:no_face.png} --supersample 99 -o {out:fit}", 2, {"--supersample"}},
      {"opt_reconstruct_refine_steps", "reconstruct {in:no_face.png} --random-weights --refine-steps -5 -o {out:a.avatar}",
       2, {"refine"}},
      {"opt_reconstruct_config", "reconstruct {in:no_face.png} --random-weights --config huge -o {out:a.avatar}", 2,
       {"config"}},
      {"opt_render_pitch", "render {in:garbage.avatar} --pitch 95 -o {out:r.png}", 2, {"pitch"}},
      {"opt_render_yaw_nan", "render {in:garbage.avatar} --yaw nan -o {out:r.png}", 2, {"yaw"}},
      {"opt_render_mode", "render {in:garbage.avatar} --mode ultra -o {out:r.png}", 2, {"render mode"}},
      {"opt_render_expr_nan", "render {in:garbage.avatar} --expr smile=nan -o {out:r.png}", 2, {"--expr"}},
      {"opt_render_expr_form", "render {in:garbage.avatar} --expr smile -o {out:r.png}", 2, {"--expr"}},
      {"opt_animate_fps_zero", "animate {in:no_face.png} --fps 0 --view orbit -o {out:c.mp4}", 2, {"--fps"}},
      {"opt_animate_fps_huge", "animate {in:no_face.png} --fps 1e9 --view orbit -o {out:c.mp4}", 2, {"--fps"}},
      {"opt_animate_seconds_nan", "animate {in:no_face.png} --seconds nan --view orbit -o {out:c.mp4}", 2, {"--seconds"}},
      {"opt_animate_width_odd", "animate {in:no_face.png} --width 65 --view orbit -o {out:c.mp4}", 2, {"width"}},
      {"opt_animate_zoom", "animate {in:no_face.png} --zoom 100 --view orbit -o {out:c.mp4}", 2, {"zoom"}},
      {"opt_animate_view", "animate {in:no_face.png} --view sideways -o {out:c.mp4}", 2, {"view"}},
      {"opt_animate_format", "animate {in:no_face.png} --format gif --view orbit -o {out:c.gif}", 2, {"format"}},
      {"opt_dataset_size", "dataset build --out {out:ds} --size 100", 2, {"size"}},
      {"opt_dataset_sub", "dataset shuffle", 2, {"shuffle"}},
      {"opt_dataset_inspect_pairs", "dataset inspect {in:ds_garbage_shard} --pairs 0", 2, {"--pairs"}},
      {"opt_train_batch", "train --config tiny --data {in:ds_garbage_shard} --out {out:run} --batch-size 0", 2,
       {"--batch-size"}},
      {"opt_train_steps", "train --config tiny --data {in:ds_garbage_shard} --out {out:run} --steps -1", 2, {"--steps"}},
      {"opt_train_fraction", "train --config tiny --data {in:ds_garbage_shard} --out {out:run} --synthetic-fraction 2", 2,
       {"--synthetic-fraction"}},
      {"opt_train_lr_nan", "train --config tiny --data {in:ds_garbage_shard} --out {out:run} --lr nan", 2, {"lr"}},
      {"opt_train_config", "train --config enormous --data {in:ds_garbage_shard} --out {out:run}", 2, {"--config"}},
      {"opt_eval_split", "eval --checkpoint {in:valid.ckpt} --data {in:ds_garbage_shard} --split test --out {out:e}", 2,
       {"split"}},
      {"opt_eval_max_pairs", "eval --checkpoint {in:valid.ckpt} --data {in:ds_garbage_shard} --max-pairs -2 --out {out:e}",
       2, {"pairs"}},
  };
  all.insert(all.end(), options.begin(), options.end());
  return all;
}

// ---------------------------------------------------------------------------------------------

// Every entry under `dir` (recursive, hidden ones too), relative, sorted.
std::vector<std::string> Tree(const fs::path& dir) {
  std::vector<std::string> names;
  for (auto it = fs::recursive_directory_iterator(dir); it != fs::recursive_directory_iterator(); ++it)
    names.push_back(fs::relative(it->path(), dir).string());
  std::sort(names.begin(), names.end());
  return names;
}

std::string Quote(const std::string& s) { return "'" + s + "'"; }

class BadInput : public ::testing::TestWithParam<Case> {};

TEST_P(BadInput, ClearErrorDocumentedExitCodeNothingWritten) {
  const Case& c = GetParam();
  TempDir dir;
  const fs::path in = dir / "in", out = dir / "out";
  fs::create_directories(in);
  fs::create_directories(out);
  Corpus corpus(in);
  // Expand the placeholders (making the corpus files the case uses).
  std::string args = c.args;
  std::vector<std::string> names;
  for (size_t at; (at = args.find('{')) != std::string::npos;) {
    const size_t end = args.find('}', at);
    ASSERT_NE(end, std::string::npos) << c.args;
    const std::string key = args.substr(at + 1, end - at - 1);
    std::string value;
    if (key == "portrait") {
      value = Quote(Corpus::Portrait());
    } else if (key == "missing") {
      value = Quote((in / "missing.jpg").string());
    } else if (key.rfind("in:", 0) == 0) {
      value = Quote(corpus.Get(key.substr(3)).string());
      names.push_back(key.substr(3));
    } else if (key.rfind("out:", 0) == 0) {
      value = Quote((out / key.substr(4)).string());
    } else {
      FAIL() << "unknown placeholder {" << key << "}";
    }
    args.replace(at, end - at + 1, value);
  }
  if (::testing::Test::HasFatalFailure() || ::testing::Test::HasNonfatalFailure()) return;
  const std::vector<std::string> inputs_before = Tree(in);

  // The case's own working folder is the output folder, so a default output path lands there too.
  const ProcessResult r = avatar::testing::RunProcess(
      "timeout -k 10 " + std::to_string(kCaseTimeoutSeconds) + " " + Quote(AVATAR_STUDIO_EXE) + " " + args,
      "cd " + Quote(out.string()) + " && env -u DISPLAY -u WAYLAND_DISPLAY -u QT_QPA_PLATFORM AVATAR_THREADS=2");
  const std::string said = r.err + r.out;
  SCOPED_TRACE("avatar-studio " + args + "\nstdout:\n" + r.out + "\nstderr:\n" + r.err);

  ASSERT_NE(r.exit_code, 124) << "hung: still running after " << kCaseTimeoutSeconds << " s";
  ASSERT_NE(r.exit_code, -1) << "killed by a signal (a crash)";
  EXPECT_EQ(r.exit_code, c.exit_code);
  EXPECT_EQ(said.find("internal error"), std::string::npos) << "an unexpected exception reached the command";
  EXPECT_EQ(said.find("terminate called"), std::string::npos);
  if (c.exit_code != 0) {
    // The message names the file that is wrong: the first corpus file that is not a valid helper
    // (an option case names its flag instead).
    const auto bad = std::find_if(names.begin(), names.end(), [](const std::string& n) { return n.rfind("valid.", 0) != 0; });
    if (c.name.rfind("opt_", 0) != 0 && bad != names.end()) {
      EXPECT_NE(r.err.find(*bad), std::string::npos) << "the message does not name '" << *bad << "'";
    }
    for (const auto& word : c.words) EXPECT_NE(r.err.find(word), std::string::npos) << "expected '" << word << "'";
    EXPECT_TRUE(Tree(out).empty()) << "files were written:\n" << ::testing::PrintToString(Tree(out));
  } else {
    for (const auto& word : c.words) EXPECT_NE(r.out.find(word), std::string::npos) << "expected '" << word << "'";
    EXPECT_EQ(Tree(out), c.written);
    for (const auto& image : c.written) {
      const cv::Mat written = LoadImageBgr(out / image);
      EXPECT_EQ(written.size(), cv::Size(80, 60));
    }
  }
  EXPECT_EQ(Tree(in), inputs_before) << "the input folder changed";
}

INSTANTIATE_TEST_SUITE_P(Corpus, BadInput, ::testing::ValuesIn(AllCases()),
                         [](const ::testing::TestParamInfo<Case>& info) { return info.param.name; });

TEST(BadInputCorpus, HasAtLeastEightyFilesOverEveryCommand) {
  std::set<std::string> files, commands;
  for (const Case& c : AllCases()) {
    commands.insert(c.args.substr(0, c.args.find(' ')));
    for (size_t at = c.args.find("{in:"); at != std::string::npos; at = c.args.find("{in:", at + 1))
      files.insert(c.args.substr(at + 4, c.args.find('}', at) - at - 4));
  }
  files.erase("valid.mp4");
  files.erase("valid.ckpt");
  files.erase("valid.avatar");
  EXPECT_GE(files.size(), 80u) << ::testing::PrintToString(files);
  std::cout << "bad-input corpus: " << files.size() << " files, " << AllCases().size() << " cases over "
            << commands.size() << " commands\n";
  for (const char* command : {"view", "analyze", "fit", "reconstruct", "render", "animate", "dataset", "train", "eval"})
    EXPECT_EQ(commands.count(command), 1u) << command;
  // Case names are unique (gtest needs that) and files are named once.
  std::set<std::string> names;
  for (const Case& c : AllCases()) EXPECT_TRUE(names.insert(c.name).second) << c.name;
}

}  // namespace
}  // namespace avatar
