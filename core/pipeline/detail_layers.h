#pragma once
// The layers of one frame of the detail path (DetailFrameSource::RenderLayers), apart from the
// source itself so that the fusion net's input packing (fusion_input.h) can read them without
// the detail source depending on it the other way round.

#include <opencv2/core.hpp>

#include "core/pipeline/frame_source.h"

namespace avatar {

// Everything one detail frame is made of, at the output size: the geometric composite and the
// layers that say where each of its pixels came from (the fusion net's inputs, fusion_input.h).
struct DetailLayers {
  RenderedFrame frame;   // the geometric composite: what Render returns
  cv::Mat network;       // CV_8UC3 the base frame's colour before any detail
  cv::Mat face_weight;   // CV_32FC1 in [0,1] the photo's face warp's blend weight
  cv::Mat depth_weight;  // CV_32FC1 in [0,1] the depth warp's blend weight (zeros without the proxy)
  cv::Mat face;          // CV_8UC1 255 where the face mesh covers the pixel
  cv::Mat eye_mouth;     // CV_8UC1 255 on the target's eyes and mouth (the photo's region through the mesh)
};

}  // namespace avatar
