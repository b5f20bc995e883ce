#pragma once
// CPU triangle rasterizer: z-buffered, top-left fill rule (adjacent triangles share edges without
// cracks or double coverage), perspective-correct barycentrics. Pixel (i, j) is sampled at its
// centre (i + 0.5, j + 0.5).

#include <functional>
#include <vector>

#include <opencv2/core.hpp>

namespace avatar::morphable {

// One projected vertex: pixel position and camera depth (> 0 for visible points).
struct ScreenVertex {
  double x = 0.0;
  double y = 0.0;
  double depth = 1.0;
};

struct RasterBuffers {
  cv::Mat triangle;  // [H,W] CV_32SC1 triangle index, -1 where nothing is drawn
  cv::Mat bary;      // [H,W] CV_32FC3 perspective-correct barycentric weights of the triangle's vertices
  cv::Mat depth;     // [H,W] CV_32FC1 camera depth, +inf where nothing is drawn
};

// Calls fn(x, y, b0, b1, b2) with screen-space barycentrics for every pixel whose centre the
// triangle covers under the top-left rule (either winding). Degenerate triangles cover nothing.
void ForEachCoveredPixel(const ScreenVertex& a, const ScreenVertex& b, const ScreenVertex& c, cv::Size size,
                         const std::function<void(int, int, double, double, double)>& fn);

// Rasterizes all triangles with a depth test (nearest wins; ties keep the lower index).
// Triangles with a vertex at depth <= near are skipped. Throws InvalidInput on bad indices or
// an empty size.
RasterBuffers Rasterize(const std::vector<ScreenVertex>& vertices, const std::vector<cv::Vec3i>& triangles,
                        cv::Size size, double near = 1e-6);

}  // namespace avatar::morphable
