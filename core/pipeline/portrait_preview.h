#pragma once
// The headless counterpart of the studio's viewport at this stage: a portrait loaded by
// the same code as the GUI and laid out the way the viewport shows it.

#include <filesystem>
#include <string>

#include <opencv2/core.hpp>

#include "core/util/run_context.h"

namespace avatar {

struct PreviewOptions {
  // Width of the viewport image in pixels.
  int width = 800;
  // Height of the viewport image in pixels.
  int height = 800;

  template <typename V>
  void Visit(V&& v) {
    v("width", width, "Viewport width in pixels");
    v("height", height, "Viewport height in pixels");
  }
  // Throws InvalidOptions when the size is outside 16..8192.
  void Validate() const;
};

// Fits `image` (BGR8) inside a width x height canvas, centred on black, keeping its
// aspect ratio. Returns the canvas and, in `placed`, where the image landed.
cv::Mat LetterboxImage(const cv::Mat& image, int width, int height, cv::Rect* placed = nullptr);

// Loads `portrait` (LoadImageBgr) and returns the viewport image. Throws like LoadImageBgr.
cv::Mat RenderPortraitPreview(const std::filesystem::path& portrait, const PreviewOptions& options, RunContext& ctx);

}  // namespace avatar
