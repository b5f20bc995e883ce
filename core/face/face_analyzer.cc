#include "core/face/face_analyzer.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <map>
#include <memory>
#include <mutex>
#include <numeric>
#include <sstream>

#include <opencv2/imgproc.hpp>

#include "core/face/blazeface.h"
#include "core/face/face_geometry.h"
#include "core/face/identity_net.h"
#include "core/face/warp.h"
#include "core/io/data_paths.h"
#include "core/io/tfjs_graph.h"
#include "core/util/error.h"
#include "core/util/options.h"
#include "core/util/timer.h"

namespace avatar::face {
namespace {

constexpr int kMeshInput = 192;
constexpr int kMatteInput = 256;
// Facemesh crops are the face box (or landmark box) enlarged by this factor.
constexpr float kMeshRoiScale = 1.5f;
// Images with a short side below this are not tiled: no face the full-range detector can find
// (its finest anchor grid has a 16 px stride) fits across them, and tiling such a strip only
// multiplies detector runs.
constexpr int kMinTiledFacePx = 16;

io::TfjsGraph LoadModel(const DataPaths& paths, const std::string& name, const std::string& purpose) {
  const auto file = paths.Require("models/" + name + ".json", purpose);
  return io::TfjsGraph(file);
}

void CheckImage(const cv::Mat& bgr) {
  AVATAR_CHECK_INPUT(!bgr.empty()) << "the image is empty";
  AVATAR_CHECK_INPUT(bgr.type() == CV_8UC3) << "expected an 8-bit BGR image (LoadImageBgr gives one)";
}

// Image -> crop pixels for a square crop of side `size` around `centre`, rotated by `angle`
// (radians; the crop's x axis follows that direction in the image), sampled at n x n.
cv::Matx23d RoiTransform(const cv::Point2f& centre, float size, float angle, int n) {
  const double s = n / static_cast<double>(size);
  const double c = std::cos(angle), si = std::sin(angle);
  // crop = s * R(-angle) * (p - centre) + n/2
  return cv::Matx23d(s * c, s * si, -s * (c * centre.x + si * centre.y) + n / 2.0,  //
                     -s * si, s * c, -s * (-si * centre.x + c * centre.y) + n / 2.0);
}

bool Touches(const cv::Rect2f& box, const cv::Rect& tile, const cv::Size& image, float margin) {
  // A box touching a tile edge that is not an image edge is probably a cut face.
  return (box.x < tile.x + margin && tile.x > 0) || (box.y < tile.y + margin && tile.y > 0) ||
         (box.br().x > tile.br().x - margin && tile.br().x < image.width) ||
         (box.br().y > tile.br().y - margin && tile.br().y < image.height);
}

}  // namespace

void FaceAnalyzerOptions::Validate() const {
  AVATAR_CHECK_OPTION(min_score > 0.0f && min_score < 1.0f) << "--min-score must be in (0,1), got " << min_score;
  AVATAR_CHECK_OPTION(nms_iou > 0.0f && nms_iou < 1.0f) << "--nms-iou must be in (0,1), got " << nms_iou;
  AVATAR_CHECK_OPTION(min_face_px >= 1) << "--min-face-px must be positive";
  AVATAR_CHECK_OPTION(sharp_face_px >= min_face_px)
      << "--sharp-face-px must be at least --min-face-px (" << min_face_px << "), got " << sharp_face_px;
  AVATAR_CHECK_OPTION(face_index >= -1) << "--face-index must be -1 (main face) or a face number >= 0";
  AVATAR_CHECK_OPTION(crop_size >= 64 && crop_size <= 4096) << "--crop-size must be in [64,4096]";
  AVATAR_CHECK_OPTION(crop_scale >= 0.5 && crop_scale <= 4.0) << "--crop-scale must be in [0.5,4]";
  AVATAR_CHECK_OPTION(mask_dilation_px >= 0 && mask_dilation_px <= 64) << "--mask-dilation-px must be in [0,64]";
  AVATAR_CHECK_OPTION(min_mesh_confidence >= 0.0f && min_mesh_confidence < 1.0f) << "--min-mesh-confidence must be in [0,1)";
  AVATAR_CHECK_OPTION(min_face_presence >= 0.0f && min_face_presence <= min_mesh_confidence)
      << "--min-face-presence must be in [0, --min-mesh-confidence], got " << min_face_presence;
  AVATAR_CHECK_OPTION(max_abs_yaw > 0.0f && max_abs_yaw <= 180.0f) << "--max-abs-yaw must be in (0,180]";
}

struct FaceAnalyzer::Models {
  std::unique_ptr<BlazeFace> back;
  std::unique_ptr<BlazeFace> front;
  std::unique_ptr<io::TfjsGraph> mesh;
  std::unique_ptr<io::TfjsGraph> selfie;
  std::unique_ptr<IdentityNet> identity;
};

FaceAnalyzer::FaceAnalyzer(const FaceAnalyzerOptions& options) : models_(std::make_unique<Models>()), options_(options) {
  options_.Validate();
  const DataPaths paths = DataPaths::Resolve(options_.data_dir);
  models_->back = std::make_unique<BlazeFace>(LoadModel(paths, "blazeface-back", "face detection"), false);
  models_->front = std::make_unique<BlazeFace>(LoadModel(paths, "blazeface-front", "face detection"), true);
  models_->mesh = std::make_unique<io::TfjsGraph>(LoadModel(paths, "facemesh", "face landmarks"));
  models_->selfie = std::make_unique<io::TfjsGraph>(LoadModel(paths, "selfie", "person matting"));
  models_->identity = std::make_unique<IdentityNet>(options_.data_dir);
}

FaceAnalyzer::~FaceAnalyzer() = default;

int MainFaceIndex(const std::vector<Detection>& faces, const cv::Size& image) {
  const double side = std::max(image.width, image.height);
  const cv::Point2d mid(image.width / 2.0, image.height / 2.0);
  int best = -1;
  double best_rank = -1e30;
  for (size_t i = 0; i < faces.size(); ++i) {
    const auto& b = faces[i].box;
    const cv::Point2d c(b.x + b.width / 2.0, b.y + b.height / 2.0);
    const double rank = std::max(b.width, b.height) / side - 0.5 * cv::norm(c - mid) / side;
    if (rank > best_rank) {
      best_rank = rank;
      best = static_cast<int>(i);
    }
  }
  return best;
}

std::vector<Detection> FaceAnalyzer::Detect(const cv::Mat& bgr) const {
  CheckImage(bgr);
  const cv::Rect whole(0, 0, bgr.cols, bgr.rows);
  std::vector<Detection> all = models_->back->DetectRegion(bgr, whole, options_.min_score);
  for (const auto& d : models_->front->DetectRegion(bgr, whole, options_.min_score)) all.push_back(d);
  const int long_side = std::max(bgr.cols, bgr.rows);
  const int input = models_->back->InputSize();
  const int short_side = std::min(bgr.cols, bgr.rows);
  if (options_.tile_large_images && long_side > 3 * input && short_side >= kMinTiledFacePx) {
    // Square tiles of half the long side, overlapping by a quarter, so a face up to a quarter
    // of the long side lies wholly inside some tile at twice the resolution. On a strip whose
    // short side is below the detector input, a tile stretches to the input size along the
    // strip (letterboxed, not upscaled), which bounds the tile count by long side / input.
    const int tile = std::min(long_side / 2, short_side);
    auto starts = [&](int extent, int side) {
      const int step = std::max(1, side * 3 / 4);
      std::vector<int> s;
      for (int p = 0;; p += step) {
        if (p + side >= extent) {
          s.push_back(std::max(0, extent - side));
          break;
        }
        s.push_back(p);
      }
      return s;
    };
    const int tile_w = std::min(bgr.cols, std::max(tile, input));
    const int tile_h = std::min(bgr.rows, std::max(tile, input));
    for (int y : starts(bgr.rows, tile_h)) {
      for (int x : starts(bgr.cols, tile_w)) {
        const cv::Rect region(x, y, std::min(tile_w, bgr.cols - x), std::min(tile_h, bgr.rows - y));
        for (const auto& d : models_->back->DetectRegion(bgr, region, options_.min_score)) {
          if (!Touches(d.box, region, bgr.size(), 2.0f)) all.push_back(d);
        }
      }
    }
  }
  std::vector<Detection> faces = WeightedNms(all, options_.nms_iou);
  // Two boxes where the smaller lies mostly inside the other are one face seen at two scales
  // (or a face and a face-like region around it): keep the better-scored one.
  std::vector<Detection> kept;
  for (const auto& d : faces) {  // by decreasing score
    bool overlaps = false;
    for (const auto& k : kept) {
      overlaps = overlaps || (d.box & k.box).area() > 0.5f * std::min(d.box.area(), k.box.area());
    }
    if (!overlaps) kept.push_back(d);
  }
  for (auto& d : kept) {
    // Keep boxes inside the image bounds' neighbourhood and finite.
    d.score = std::clamp(d.score, 0.0f, 1.0f);
  }
  // Main face first, then by rank.
  std::vector<Detection> ordered;
  while (!kept.empty()) {
    const int i = MainFaceIndex(kept, bgr.size());
    ordered.push_back(kept[i]);
    kept.erase(kept.begin() + i);
  }
  return ordered;
}

Landmarks FaceAnalyzer::RunMesh(const cv::Mat& bgr, const cv::Point2f& centre, float size, float angle) const {
  const cv::Matx23d to_crop = RoiTransform(centre, size, angle, kMeshInput);
  // [1,192,192,3] RGB in [0,1]
  const torch::Tensor input = WarpToTensor(bgr, to_crop, kMeshInput, kMeshInput, 0.0f, 1.0f);
  const auto out = models_->mesh->Run(input, {"output_mesh", "output_faceflag"});
  const torch::Tensor mesh = out[0].reshape({kMeshPoints, 3}).contiguous();  // crop pixels
  Landmarks lm;
  lm.confidence = std::clamp(out[1].reshape({-1})[0].item<float>(), 0.0f, 1.0f);
  lm.points.resize(kMeshPoints);
  const float* m = mesh.data_ptr<float>();
  for (int i = 0; i < kMeshPoints; ++i) lm.points[i] = cv::Point3f(m[3 * i], m[3 * i + 1], m[3 * i + 2]);
  return TransformLandmarks(lm, InvertAffine(to_crop));
}

Landmarks FaceAnalyzer::MeshFromLandmarks(const cv::Mat& bgr, const Landmarks& previous) const {
  CheckImage(bgr);
  AVATAR_CHECK_INPUT(previous.points.size() == static_cast<size_t>(kMeshPoints)) << "need 468 previous landmarks";
  const auto& a = previous.points[mesh_index::kRightEyeOuter];
  const auto& b = previous.points[mesh_index::kLeftEyeOuter];
  const float angle = std::atan2(b.y - a.y, b.x - a.x);
  // Bounding box in the rotated frame.
  const float c = std::cos(angle), s = std::sin(angle);
  float lo_u = 1e30f, hi_u = -1e30f, lo_v = 1e30f, hi_v = -1e30f;
  for (const auto& p : previous.points) {
    const float u = c * p.x + s * p.y, v = -s * p.x + c * p.y;
    lo_u = std::min(lo_u, u);
    hi_u = std::max(hi_u, u);
    lo_v = std::min(lo_v, v);
    hi_v = std::max(hi_v, v);
  }
  const float mu = (lo_u + hi_u) / 2, mv = (lo_v + hi_v) / 2;
  const cv::Point2f centre(c * mu - s * mv, s * mu + c * mv);
  const float size = std::max(hi_u - lo_u, hi_v - lo_v) * kMeshRoiScale;
  AVATAR_CHECK_INPUT(std::isfinite(size) && size > 1.0f) << "degenerate previous landmarks";
  return RunMesh(bgr, centre, size, angle);
}

Landmarks FaceAnalyzer::Mesh(const cv::Mat& bgr, const Detection& face) const {
  CheckImage(bgr);
  const cv::Point2f centre(face.box.x + face.box.width / 2, face.box.y + face.box.height / 2);
  const auto& re = face.keypoints[0];
  const auto& le = face.keypoints[1];
  const float angle = std::atan2(le.y - re.y, le.x - re.x);
  const float size = std::max(face.box.width, face.box.height) * kMeshRoiScale;
  AVATAR_CHECK_INPUT(std::isfinite(size) && size > 1.0f) << "degenerate face box";
  const Landmarks first = RunMesh(bgr, centre, size, angle);
  return MeshFromLandmarks(bgr, first);
}

cv::Mat FaceAnalyzer::Matte(const cv::Mat& bgr) const {
  CheckImage(bgr);
  const cv::Matx23d m(static_cast<double>(kMatteInput) / bgr.cols, 0, 0.5 * kMatteInput / bgr.cols - 0.5, 0,
                      static_cast<double>(kMatteInput) / bgr.rows, 0.5 * kMatteInput / bgr.rows - 0.5);
  const torch::Tensor input = WarpToTensor(bgr, m, kMatteInput, kMatteInput, 0.0f, 1.0f);
  // [1,256,256,1] person probability
  torch::Tensor mask = models_->selfie->Run(input, {"activation_10"})[0].reshape({kMatteInput, kMatteInput}).contiguous();
  cv::Mat small(kMatteInput, kMatteInput, CV_32FC1, mask.data_ptr<float>());
  cv::Mat out;
  cv::resize(small, out, bgr.size(), 0, 0, cv::INTER_LINEAR);
  cv::min(cv::max(out, 0.0), 1.0, out);
  return out;
}

std::vector<float> FaceAnalyzer::Embedding(const cv::Mat& bgr, const Landmarks& lm) const {
  CheckImage(bgr);
  AVATAR_CHECK_INPUT(lm.points.size() == static_cast<size_t>(kMeshPoints)) << "embedding needs 468 landmarks";
  // fr_feature.onnx after the ArcFace five-point alignment (identity_net.h). It replaced
  // mobilefacenet, whose vectors barely separate people (docs/DEVIATIONS.md).
  return models_->identity->Embed(bgr, lm);
}

AlignedPortrait FaceAnalyzer::AnalyzePortrait(const cv::Mat& bgr, RunContext& ctx, PortraitReport* report) const {
  CheckImage(bgr);
  PortraitReport local;
  PortraitReport& rep = report != nullptr ? *report : local;
  rep = PortraitReport();
  Timer timer;
  auto stage = [&](const char* name, double fraction) {
    rep.timings.push_back({name, timer.Milliseconds()});
    timer.Restart();
    ctx.Report("analyse face", fraction, name);
  };
  ctx.ThrowIfCancelled();
  rep.faces = Detect(bgr);
  stage("detect", 0.3);
  AVATAR_CHECK_INPUT(!rep.faces.empty())
      << "no face found in the image (" << bgr.cols << "x" << bgr.rows << "); use a photo with a clearly visible face";
  const int index = options_.face_index < 0 ? 0 : options_.face_index;
  AVATAR_CHECK_INPUT(index < static_cast<int>(rep.faces.size()))
      << "face " << options_.face_index << " requested but only " << rep.faces.size() << " face(s) found (0.."
      << rep.faces.size() - 1 << ")";
  rep.selected = index;
  const Detection& face = rep.faces[index];
  const float face_px = std::max(face.box.width, face.box.height);
  AVATAR_CHECK_INPUT(face_px >= options_.min_face_px)
      << "the face is too small (" << static_cast<int>(face_px) << " px, at least " << options_.min_face_px
      << " px needed, " << options_.sharp_face_px << " px for a sharp result); use a larger or closer photo";
  const Landmarks lm = Mesh(bgr, face);
  stage("mesh", 0.5);
  // The landmark model's face-presence output tells a detector false positive (a drawing, a
  // pattern) from a real face that is hard to read.
  AVATAR_CHECK_INPUT(lm.confidence >= options_.min_face_presence)
      << "no face found in the image (" << bgr.cols << "x" << bgr.rows << "): what the detector found ("
      << static_cast<int>(face_px) << " px box) is not a human face to the landmark model (face presence "
      << std::setprecision(2) << lm.confidence << "); use a photo with a clearly visible face";
  AVATAR_CHECK_INPUT(lm.confidence >= options_.min_mesh_confidence)
      << "the face landmarks are unreliable (confidence " << std::setprecision(2) << lm.confidence
      << "); the face may be occluded, blurred or seen from the side: use a frontal photo";
  rep.image_landmarks = lm;
  AlignedPortrait out;
  out.pose = HeadPoseFromLandmarks(lm);
  AVATAR_CHECK_INPUT(std::abs(out.pose.yaw) <= options_.max_abs_yaw)
      << "the face is turned too far to the side (yaw " << static_cast<int>(std::lround(out.pose.yaw))
      << " degrees, at most " << options_.max_abs_yaw
      << "): beyond that the face landmarks and the face-model fit drift (about 3.5x their frontal error, "
         "measured on renders at known turns), so the avatar would be distorted; use a more frontal photo";
  stage("pose", 0.55);
  const int size = options_.crop_size;
  out.crop_from_image = CropTransform(lm, size, options_.crop_scale);
  out.image_unmatted = WarpImage(bgr, out.crop_from_image, size, size);
  out.landmarks = TransformLandmarks(lm, out.crop_from_image);
  if (face_px < options_.sharp_face_px) {
    const cv::Matx23d& m = out.crop_from_image;
    const double upsampling = std::sqrt(std::abs(m(0, 0) * m(1, 1) - m(0, 1) * m(1, 0)));
    std::ostringstream w;
    w << std::fixed << std::setprecision(1) << "the face is small (" << static_cast<int>(face_px) << " px; "
      << options_.sharp_face_px << " px or more gives a sharp result): its " << size << " px crop is upsampled "
      << upsampling << "x, so the avatar will be soft; use a larger or closer photo for a sharp one";
    out.warnings.push_back(w.str());
  }
  stage("crop", 0.6);
  if (options_.matte) {
    out.matte = Matte(out.image_unmatted);
  } else {
    out.matte = cv::Mat(size, size, CV_32FC1, cv::Scalar(1.0f));
  }
  cv::Mat matte3;
  cv::cvtColor(out.matte, matte3, cv::COLOR_GRAY2BGR);
  cv::Mat f;
  out.image_unmatted.convertTo(f, CV_32FC3);
  cv::multiply(f, matte3, f);
  f.convertTo(out.image, CV_8UC3);
  stage("matte", 0.8);
  out.eye_mouth_mask = EyeMouthMask(out.landmarks, size, (options_.mask_dilation_px * size + 256) / 512);
  stage("masks", 0.85);
  if (options_.embedding) out.embedding = Embedding(bgr, lm);
  stage("embedding", 1.0);
  return out;
}

float IdentitySimilarity(const std::vector<float>& a, const std::vector<float>& b) {
  AVATAR_CHECK_INPUT(!a.empty() && a.size() == b.size())
      << "identity embeddings must be non-empty and of equal length (got " << a.size() << " and " << b.size() << ")";
  double dot = 0, na = 0, nb = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    dot += static_cast<double>(a[i]) * b[i];
    na += static_cast<double>(a[i]) * a[i];
    nb += static_cast<double>(b[i]) * b[i];
  }
  AVATAR_CHECK_INPUT(na > 0 && nb > 0 && std::isfinite(dot)) << "identity embedding is zero or not finite";
  return static_cast<float>(std::clamp(dot / std::sqrt(na * nb), -1.0, 1.0));
}

FaceTracker::FaceTracker(const FaceAnalyzer& analyzer, const FaceTrackerOptions& options)
    : analyzer_(analyzer), options_(options) {}

FaceTracker::~FaceTracker() = default;

void FaceTracker::Reset() {
  tracking_ = false;
  previous_ = Landmarks();
  filters_.clear();
}

TrackedFace FaceTracker::Track(const cv::Mat& bgr, double t) {
  TrackedFace out;
  Landmarks lm;
  if (tracking_) {
    lm = analyzer_.MeshFromLandmarks(bgr, previous_);
    if (lm.confidence < options_.min_confidence) tracking_ = false;
  }
  if (!tracking_) {
    out.redetected = true;
    const auto faces = analyzer_.Detect(bgr);
    if (faces.empty()) {
      Reset();
      return out;
    }
    lm = analyzer_.Mesh(bgr, faces.front());
    if (lm.confidence < options_.min_confidence) {
      Reset();
      out.confidence = lm.confidence;
      return out;
    }
    // A re-detected face may be another person or a jump: restart the filters.
    filters_.clear();
  }
  tracking_ = true;
  previous_ = lm;
  out.found = true;
  out.raw = lm;
  out.confidence = lm.confidence;
  HeadPose pose = HeadPoseFromLandmarks(lm);
  out.landmarks = lm;
  if (options_.smooth) {
    if (filters_.empty()) {
      filters_.assign(3 * kMeshPoints, OneEuroFilter(options_.landmark_filter));
      for (int k = 0; k < 3; ++k) filters_.emplace_back(options_.pose_filter);
    }
    for (int i = 0; i < kMeshPoints; ++i) {
      auto& p = out.landmarks.points[i];
      p.x = static_cast<float>(filters_[3 * i].Filter(p.x, t));
      p.y = static_cast<float>(filters_[3 * i + 1].Filter(p.y, t));
      p.z = static_cast<float>(filters_[3 * i + 2].Filter(p.z, t));
    }
    pose.yaw = static_cast<float>(filters_[3 * kMeshPoints].Filter(pose.yaw, t));
    pose.pitch = static_cast<float>(filters_[3 * kMeshPoints + 1].Filter(pose.pitch, t));
    pose.roll = static_cast<float>(filters_[3 * kMeshPoints + 2].Filter(pose.roll, t));
  }
  out.pose = pose;
  return out;
}

const FaceAnalyzer& SharedFaceAnalyzer(const FaceAnalyzerOptions& options) {
  static std::mutex mutex;
  static std::map<std::string, std::unique_ptr<FaceAnalyzer>> analyzers;
  const std::string key = options.data_dir + "\n" + options::ToJson(options).dump();
  std::lock_guard<std::mutex> lock(mutex);
  auto& slot = analyzers[key];
  if (!slot) {
    try {
      slot = std::make_unique<FaceAnalyzer>(options);
    } catch (...) {
      analyzers.erase(key);
      throw;
    }
  }
  return *slot;
}

}  // namespace avatar::face
