#pragma once
// Per-portrait refinement: after the one-shot forward, the cached planes T_c and T_p of an
// avatar are optimised (Adam) so that the render at the source camera matches the user's
// matted photo. The network's weights are not changed (the session's model is shared).
//
// Objective per step, at the source camera C_s and render size R:
//   l1_weight         * L1(I, matted source)                           I = R_V(T_c + T_p + T_e0, C_s)
// + perceptual_weight * perceptual (MobileNetV2)(I, matted source)     (core/train/perceptual.h)
// + neutral_weight    * NeutralLoss(R_V(T_c, C_s), I_neu, M_neu)       (when the target has I_neu)
// + tv_weight         * density TV at tv_points random points          (drawn from `seed`)
// + prior_weight      * mean((T_c - T_c^0)^2 + (T_p - T_p^0)^2)        keeps unseen sides near the one-shot planes
// T_e0 are the expression planes of the neutral controls (what Animate adds for Expression{}),
// held fixed. Gradients are clipped to grad_clip (global norm). A step whose loss, gradient or
// planes are not finite ends the refinement with the last good planes (stopped_by "non-finite").
// The planes returned are the evaluated ones with the lowest objective without the random TV
// term (never worse than the one-shot planes on it). Deterministic for a given seed, device and thread count.
//
// Progress: RunContext::Report("refine", fraction, "step k/N ..."); cancellation is checked
// between steps and around each term's forward and backward pass (each term is its own pass,
// so the longest piece of work between checks is one render's backward; throws Cancelled).

#include <string>

#include <opencv2/core.hpp>

#include "core/face/face_types.h"
#include "core/pipeline/session.h"
#include "core/util/run_context.h"

namespace avatar {

struct SourceAnalysis;

struct RefineOptions {
  // Optimisation steps (0 = none unless `seconds` is set; both set: whichever ends first).
  int steps = 100;
  // Wall-clock budget in seconds (0 = no limit; with steps 0 the budget alone ends the run).
  double seconds = 0.0;
  // Adam learning rate on the plane values.
  double lr = 0.05;
  // Loss weights.
  double l1_weight = 1.0;
  double perceptual_weight = 1.0;
  double neutral_weight = 0.3;
  double tv_weight = 0.1;
  double prior_weight = 1.0;
  // Global gradient-norm clip (0 = off).
  double grad_clip = 1.0;
  // Random TV points per step.
  int tv_points = 1000;
  // Seed of the TV points.
  int seed = 0;
  // Render size of the refinement renders (0 = the model's render size).
  int resolution = 0;
  // Data folder with models/nsfwjs for the perceptual term ("" = AVATAR_DATA_DIR or the default).
  std::string data_dir;

  template <typename V>
  void Visit(V&& v) {
    v("refine_steps", steps, "Refinement steps on the source view after the one-shot reconstruction (0 = off)");
    v("refine_seconds", seconds, "Refinement time budget in seconds (0 = no limit)");
    v("refine_lr", lr, "Refinement learning rate (Adam, on the planes)");
    v("refine_l1", l1_weight, "Refinement weight of the L1 source term");
    v("refine_perceptual", perceptual_weight, "Refinement weight of the perceptual (MobileNetV2) source term");
    v("refine_neutral", neutral_weight, "Refinement weight of the neutral (morphable) term on T_c");
    v("refine_tv", tv_weight, "Refinement weight of the density TV term");
    v("refine_prior", prior_weight, "Refinement weight keeping the planes near the one-shot prediction");
    v("refine_seed", seed, "Seed of the refinement's random TV points");
  }
  // True when the options ask for any refinement.
  bool Enabled() const { return steps > 0 || seconds > 0; }
  // Throws InvalidOptions.
  void Validate() const;
};

// What the refinement fits: the matted source and (optionally) the morphable neutral render.
struct RefineTarget {
  cv::Mat image;          // BGR8 aligned portrait (matted on black is fine)
  cv::Mat matte;          // CV_32FC1 [0,1] or CV_8UC1; empty = all ones
  cv::Mat neutral_image;  // I_neu at the source camera: CV_32FC3 BGR [0,1] or CV_8UC3; empty = no neutral term
  cv::Mat neutral_mask;   // M_neu: CV_32FC1 [0,1] or CV_8UC1 (needed with neutral_image)
};
// The target of a source analysis: its portrait and matte, and I_neu / M_neu rendered from its
// morphable fit (none when the analysis has no morphable model).
RefineTarget RefineTargetFromAnalysis(const SourceAnalysis& analysis, int size = 256);

struct RefineResult {
  Avatar avatar;                 // the refined avatar (the input's planes when no step improved)
  int steps = 0;                 // optimisation steps taken
  int best_step = 0;             // steps behind the returned planes
  double seconds = 0.0;
  double loss_before = 0.0, loss_after = 0.0;  // objective of the input and returned planes
  double psnr_before = 0.0, psnr_after = 0.0;  // dB at the source camera, masked by the matte
  std::string stopped_by;        // "steps", "seconds" or "non-finite"
};

// Refines `avatar` (made by `session`) on `target`. Throws InvalidOptions, InvalidInput (empty
// or foreign avatar, bad target), ModelLoad (perceptual weights missing with perceptual_weight
// > 0), Cancelled.
RefineResult RefineAvatar(const Session& session, const Avatar& avatar, const RefineTarget& target,
                          const RefineOptions& options, RunContext& ctx);
// Same on a source analysis (RefineTargetFromAnalysis).
RefineResult RefineAvatar(const Session& session, const Avatar& avatar, const SourceAnalysis& analysis,
                          const RefineOptions& options, RunContext& ctx);

// Source-view PSNR (dB, masked by the target's matte) of the avatar's render at its source
// camera and the session's render size, as the refinement measures it.
double SourceViewPsnr(const Session& session, const Avatar& avatar, const RefineTarget& target);

}  // namespace avatar
