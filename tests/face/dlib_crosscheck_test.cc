// Cross-check of the facemesh landmarks against an independent stack: dlib's HOG face
// detector and its 68-point shape predictor (Debian libdlib-dev + libdlib-data), on the same
// photos. Error: mean distance between dlib's 68 points and the corresponding mesh vertices
// (mesh_index::Ibug68), divided by the outer-eye-corner distance (the 300-W convention).
#include <dlib/image_processing.h>
#include <dlib/image_processing/frontal_face_detector.h>
#include <dlib/opencv.h>

#include <filesystem>
#include <iostream>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "core/face/face_geometry.h"
#include "face/face_test_util.h"

namespace avatar::face {
namespace {

using testing::Analyzer;
using testing::LoadSample;

const char* const kPredictor = "/usr/share/dlib/shape_predictor_68_face_landmarks.dat";

TEST(DlibCrossCheck, MeshAgreesWithDlib68) {
  ASSERT_TRUE(std::filesystem::exists(kPredictor))
      << kPredictor << " is missing: install libdlib-data (scripts/setup does)";
  dlib::shape_predictor predictor;
  dlib::deserialize(kPredictor) >> predictor;
  dlib::frontal_face_detector detector = dlib::get_frontal_face_detector();
  double sum_all = 0.0, sum_inner = 0.0, worst = 0.0;
  int faces = 0;
  for (const char* file : {"grace_hopper.jpg", "franck_01829.jpg", "franck_02159.jpg", "franck_02683.jpg",
                           "franck_03909.jpg", "franck_04035.jpg"}) {
    const cv::Mat image = LoadSample(file);
    cv::Mat rgb;
    cv::cvtColor(image, rgb, cv::COLOR_BGR2RGB);
    dlib::cv_image<dlib::rgb_pixel> dimg(rgb);
    const auto boxes = detector(dimg);
    const auto ours = Analyzer().Detect(image);
    ASSERT_EQ(boxes.size(), 1u) << file << ": dlib found " << boxes.size() << " faces";
    ASSERT_EQ(ours.size(), 1u) << file;
    const dlib::full_object_detection shape = predictor(dimg, boxes[0]);
    ASSERT_EQ(shape.num_parts(), 68u);
    const Landmarks lm = Analyzer().Mesh(image, ours[0]);
    const auto& idx = mesh_index::Ibug68();
    const double iod = std::hypot(shape.part(45).x() - shape.part(36).x(), shape.part(45).y() - shape.part(36).y());
    ASSERT_GT(iod, 10.0);
    double e_all = 0.0, e_inner = 0.0;
    for (int k = 0; k < 68; ++k) {
      const double e = std::hypot(shape.part(k).x() - lm.points[idx[k]].x, shape.part(k).y() - lm.points[idx[k]].y);
      e_all += e;
      if (k >= 17) e_inner += e;
    }
    e_all /= 68.0 * iod;
    e_inner /= 51.0 * iod;
    std::cout << "[dlib] " << file << ": mean error / inter-ocular = " << e_all << " (68 points), " << e_inner
              << " (51 inner points)\n";
    sum_all += e_all;
    sum_inner += e_inner;
    worst = std::max(worst, e_all);
    ++faces;
  }
  std::cout << "[dlib] mean over " << faces << " faces: " << sum_all / faces << " (68), " << sum_inner / faces
            << " (inner 51); worst face " << worst << "\n";
  // Bounds: the two stacks define the jaw line differently (dlib: visible outline), so the
  // 68-point error is larger than the inner one. Measured: 0.058 (68), 0.029 (inner), worst 0.075.
  EXPECT_LT(sum_all / faces, 0.08);
  EXPECT_LT(sum_inner / faces, 0.05);
  EXPECT_LT(worst, 0.10);
}

}  // namespace
}  // namespace avatar::face
