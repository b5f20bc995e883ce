#pragma once
// The one analysis of a portrait, computed once and used by every renderer: face analysis
// (aligned 512 crop, matte, eye/mouth mask, landmarks), the morphable fit and its texture, the
// network's inputs (source camera, expression renderer) and the overlay the source panel draws.
// The neural session (Session::ReconstructFromAnalysis), the morphable preview and `fit` all
// start from it.

#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "core/face/face_analyzer.h"
#include "core/face/face_types.h"
#include "core/morphable/morphable.h"
#include "core/pipeline/frame_source.h"
#include "core/pipeline/source_fit.h"
#include "core/util/run_context.h"

namespace avatar {

struct SourceAnalysis {
  face::AlignedPortrait portrait;
  SourceFit fit;                                   // network inputs (camera C_s, I_exp renderer)
  const morphable::MorphableModel* model = nullptr;  // the default morphable model (process lifetime)
  morphable::FitResult morphable_fit;              // fit to portrait.landmarks in the 512 crop
  morphable::Texture texture;                      // sampled from the unmatted crop
  SourceOverlay overlay;                           // detections and landmarks in portrait pixels
  // What the user should be told about this portrait (one sentence each, e.g. a small face
  // gives a soft avatar); AnalyseSource also logs each one as a warning.
  std::vector<std::string> warnings;
};

// Analyses a BGR photo. `data_dir` as in SessionOptions. Throws InvalidInput (no face),
// MissingData (face models not installed or not part of this build), Cancelled.
SourceAnalysis AnalyseSource(const cv::Mat& bgr, const std::string& data_dir, RunContext& ctx);
// The same with the face analyser's options (which face, thresholds, identity embedding; its
// data_dir names the data folder): the data factory analyses its training photos through this
// call, so that training and inference preprocess a portrait identically.
SourceAnalysis AnalyseSource(const cv::Mat& bgr, const face::FaceAnalyzerOptions& analyzer, RunContext& ctx);

// The analysis of a portrait analysed before (the data factory's stored items): its aligned crop,
// matte and eye/mouth mask, and the morphable fit made then (fit.image_size = the crop's size).
// Everything derived from them (model, texture, network inputs) is computed here, as AnalyseSource
// does after the fit. Throws InvalidInput (sizes, a fit of another model), MissingData.
SourceAnalysis AnalysisFromFit(face::AlignedPortrait portrait, morphable::FitResult fit, const std::string& data_dir);

}  // namespace avatar
