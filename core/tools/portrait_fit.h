#pragma once
// The morphable fit of a portrait as `avatar-studio fit` writes it: the face model fitted to the
// aligned 512 crop's landmarks, its texture, and the images the network takes from it (I_exp of
// the source and of an edited expression at the frontal camera, I_neu / M_neu at the source
// camera), an overlay, a summary strip and fit.json (coefficients, camera label, fit error).

#include <functional>
#include <map>
#include <string>
#include <vector>

#include "core/morphable/morphable.h"
#include "core/util/run_context.h"

namespace avatar {

struct PortraitFitOptions {
  // Portrait image.
  std::string input;
  // Output folder (created); with all_faces one face_K folder per face inside it.
  std::string out_dir = "fit-out";
  // Expression edits (named controls), added to the fitted expression for I_exp_edited.
  std::map<std::string, float> edits;
  // Side of the rendered images in pixels.
  int size = 512;
  // Supersampling of the renders.
  int supersample = 2;
  // Which face: -1 = main face, k = k-th detected face.
  int face_index = -1;
  // Fit every detected face of the image (a face that cannot be analysed is skipped).
  bool all_faces = false;
  // Morphable model file ("" = the installed default model).
  std::string model;
  // Fitting.
  morphable::FitOptions fit;
  // Texture sampling.
  morphable::TextureOptions texture;
  // Folder with the installed data ("" = AVATAR_DATA_DIR, then the default cache).
  std::string data_dir;

  // Throws InvalidOptions.
  void Validate() const;
};

// The outcome for one face.
struct FaceFitOutcome {
  int face_index = -1;           // as asked (-1 = the main face)
  bool skipped = false;          // all_faces only: the face could not be analysed
  std::string skip_reason;       // the analyser's message
  morphable::FitResult fit;      // not skipped: the fit (errors in px and inter-ocular distances)
  std::string dir;               // not skipped: the folder written
};

// Fits the face (or every face) and writes the outputs. `on_face` (may be empty) gets each
// face's outcome as soon as its files are written. Throws InvalidOptions (bad options or control
// names); Io (photo, model file, output folder); ModelLoad; InvalidInput naming the photo (no
// usable face, unless all_faces); MissingData (face models); Cancelled.
std::vector<FaceFitOutcome> FitPortrait(const PortraitFitOptions& options, RunContext& ctx,
                                        const std::function<void(const FaceFitOutcome&)>& on_face = {});

}  // namespace avatar
