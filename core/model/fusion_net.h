#pragma once
// The fusion network that finishes a frame of the detail path (issue 33): a small 2D U-Net that
// looks at the geometric composite (the photo warped where it saw the surface over the upsampled
// network render), the network render itself and the masks that say where each came from, and
// predicts a residual and a blend mask:
//   out = composite + (1 - keep) * sigmoid(m) * 2 tanh(r),   keep = max(face weight, depth weight)
// (times the frame's opacity with FusionNetOptions::gate_by_opacity)
// where keep_warped (the default since fusion-8) holds the photo wherever the composite is the
// photo: a net trained without it (fusion-1..7, keep = 0) learned to soften the warped photo
// everywhere and cost 4.8 dB on the photo's own view (docs/training/README.md).
// The residual head starts at zero, so an untrained net returns the composite exactly, and the
// mask's bias at -2 (sigmoid 0.12), so that the residual learns from the first step (a mask
// started nearly shut, bias -6, left the validation loss flat over the first 250 steps of
// training: Adam moves a bias by about the learning rate per step).
//
// Input channels (FusionInputChannels, in this order; images in [-1,1], masks in [0,1]):
//   0-2  the geometric composite (RGB, as every network tensor)
//   3-5  the network render upsampled to the output size (RGB)
//   6    the face warp's blend weight        7  the depth warp's blend weight
//   8    the face mesh's coverage            9  the target's eye and mouth region
//   10   the frame's opacity
// With FusionNetOptions::turn (since fusion-9) one more plane follows, made inside the net from the
// view's turn away from the photo's (FusionTurnFraction), and the residual may also act on the
// warped photo in proportion to it: open = 1 - keep x (1 - turn fraction). At the photo's own view
// the photo is kept exactly; at a turned view the net may soften warped texture that no longer
// lines up (the SSIM study of issue 32: a blur that grows with the turn beats the sharp warp).
// Architecture: per level two 3x3 convs with LeakyReLU(0.2), a stride-2 3x3 conv down; bilinear
// x2 up, concatenation with the level's skip, two 3x3 convs; a 1x1 head to 4 channels.

#include <filesystem>
#include <string>
#include <vector>

#include <torch/torch.h>

namespace avatar {

inline constexpr int64_t kFusionInputChannels = 11;

// The frame side the fusion nets are trained at (fusion sets are built at 256 px): a detail
// source runs its net on larger frames scaled down to it and adds the net's change scaled up.
inline constexpr int64_t kFusionNetSide = 256;

// The turn at which the residual may act on the warped photo in full (degrees).
inline constexpr double kFusionFullTurnDegrees = 45.0;
// The angle between a view and the photo's, from their yaw and pitch differences (degrees).
double FusionTurnDegrees(double d_yaw, double d_pitch);

// Number of image channels at the front of the input (composite and network render); the rest
// are masks.
inline constexpr int64_t kFusionImageChannels = 6;

// The stored form of fusion inputs and targets: uint8 [B,C,H,W] (images and masks as 0..255) ->
// float [B,C,H,W] with the first `image_channels` channels in [-1,1] and the rest in [0,1]. Inference
// and training both go through the bytes, so they see the same quantised input. Throws
// InvalidInput for another dtype or rank.
torch::Tensor FusionInputFromBytes(const torch::Tensor& bytes, int64_t image_channels = kFusionImageChannels);

struct FusionNetOptions {
  int64_t in_channels = kFusionInputChannels;
  // Feature widths from the full resolution down; the last is the bottleneck's (at 1/2^(n-1)).
  std::vector<int64_t> widths = {16, 32, 64, 96};
  // The residual acts only where the photo's warps did not reach (1 - the larger of channels 6
  // and 7): where the composite is the photo, the output is the composite exactly. Weights files
  // without the flag (before fusion-8) load with it off.
  bool keep_warped = true;
  // The view's turn from the photo's is an input and opens the warped photo to the residual in
  // proportion (1 - keep x (1 - min(1, turn / kFusionFullTurnDegrees))); needs keep_warped. The
  // net then needs the turn with every input (forward's turn_degrees). Off in files before fusion-9.
  bool turn = false;
  // With turn: the face warp's photo stays kept at every turn and only the depth warp's (hair,
  // ears, neck, clothes) opens: keep = max(face weight, depth weight x (1 - turn fraction)).
  // fusion-12 opened both and gave up 0.06 identity at +-30 degrees (the net softened the face);
  // the issue-32 study measured that softening outside the face alone already gains SSIM and
  // perceptual distance at turned targets. Off in files before fusion-13.
  bool turn_keeps_face = false;
  // With turn: the share of the turn's opening that the warped photo gets, in [0,1]: the turn
  // fraction is multiplied by it before it opens the photo (keep x (1 - turn_open x fraction)).
  // fusion-13 trained with 1 and, at inference, softened the hair and the head's outline enough at
  // +-15..30 degrees to lower the orbit identity; at 1/16 it still beats the composite on every
  // validation bucket with the identity not lower (docs/PERFORMANCE.md "The detail path against
  // real targets"). An inference setting that `fusion export` may change; 1 in older files.
  double turn_open = 1.0;
  // The residual does not act on the target's eye and mouth region (input channel 9, in
  // proportion): there the composite stays, with the opened mouth's interior painted dark in the
  // lips' colour. fusion-13 painted that interior a flat grey (the clips' average of teeth and
  // dark), which lowered the orbit's mouth-opening measure (0.081 against the composite's 0.089).
  // An inference setting that `fusion export --keep-eye-mouth` turns on; off in older files.
  bool keep_eye_mouth = false;
  // The residual does not act on the face mesh's coverage (input channel 8, in proportion): the
  // whole face is the composite's (the photo where it saw the face, the fitted texture where not).
  // Once the photo's outline was cleaned of its background (compose::RefineEdgeMatte) the near
  // jaw of a turned head is the fitted texture, where the shipped net painted a haze that lowered
  // the orbit identity at +30 degrees (0.746 -> 0.722), for no gain on the real turned frames
  // (docs/PERFORMANCE.md "The photo's outline"). Includes the eyes and mouth (keep_eye_mouth). An
  // inference setting that `fusion export --keep-face` turns on; off in older files.
  bool keep_face = false;
  // The residual acts only on the frame's opaque pixels, in proportion to the opacity (input
  // channel 10): where the composite is transparent its colour is the empty background, which the
  // net has no business changing (fusion-8 lost 2.3 dB on the photo's own view there and at the
  // outline). Off in files before fusion-10.
  bool gate_by_opacity = false;
  // Throws InvalidOptions (fewer than two levels, a width outside 1..1024, no input channels,
  // keep_warped without the two warp-weight channels, turn without keep_warped, turn_keeps_face
  // without turn, turn_open outside [0,1] or other than 1 without turn, keep_eye_mouth without
  // input channel 9, keep_face without input channel 8).
  void Validate() const;
};

class FusionNetImpl : public torch::nn::Module {
 public:
  explicit FusionNetImpl(const FusionNetOptions& options = {});
  // x [B,in_channels,H,W] (H and W divisible by 2^(levels-1)) and the views' turns from the
  // photo's in degrees ([B], FusionTurnDegrees; read only by a net with options().turn, which
  // requires them) -> the finished image [B,3,H,W]. Throws InvalidInput for other shapes.
  torch::Tensor forward(const torch::Tensor& x, const torch::Tensor& turn_degrees = {});
  // The residual and the blend mask before they are combined: {r [B,3,H,W], m [B,1,H,W] in (0,1)}.
  std::pair<torch::Tensor, torch::Tensor> Heads(const torch::Tensor& x, const torch::Tensor& turn_degrees = {});
  // Where the residual may act, [B,1,H,W] in [0,1]: 1 - keep (all ones without keep_warped), and
  // with options().turn 1 - keep x (1 - s) (1 - max(face, depth x (1 - s)) with turn_keeps_face),
  // s = turn_open x turn fraction; times the opacity with gate_by_opacity, and times 1 - the
  // eye/mouth region with keep_eye_mouth.
  torch::Tensor OpenTo(const torch::Tensor& x, const torch::Tensor& turn_degrees = {}) const;
  const FusionNetOptions& options() const { return options_; }
  int64_t ParameterCount() const;

 private:
  FusionNetOptions options_;
  torch::nn::ModuleList down_{nullptr};   // per level: the two convs (Sequential)
  torch::nn::ModuleList pool_{nullptr};   // stride-2 convs between levels
  torch::nn::ModuleList up_{nullptr};     // per decoder level: the two convs after the concat
  torch::nn::Conv2d head_{nullptr};
};
TORCH_MODULE(FusionNet);

// What a fusion weights file says about itself.
struct FusionNetInfo {
  int64_t step = 0;             // training step of the weights
  std::string data_provenance;  // what they were trained on
  std::string fingerprint;      // the file's checksum (16 hex digits), on reading
  FusionNetOptions options;
};

// Writes the net's weights (float16 when `half_precision`) as a "fusion-net" tensor archive,
// atomically. Throws InvalidInput for non-finite weights, Io.
void SaveFusionNet(const std::filesystem::path& path, const FusionNet& net, const FusionNetInfo& info,
                   bool half_precision);
// The turn input of a net with options().turn: [B] degrees -> [B,1,1,1] in [0,1] (turn over
// kFusionFullTurnDegrees, clamped; non-finite turns count as full). Throws InvalidInput unless
// there is one turn per image.
torch::Tensor FusionTurnFraction(const torch::Tensor& turn_degrees, int64_t batch);

// Copies `from`'s weights into `to` (a fresh run's --init): tensors of equal shape as they are;
// the first convolution of a net with one more input channel (turn) gets the stored weights for
// the stored channels and zeros for the new one, so it computes what `from` did. Throws
// InvalidOptions when the widths differ or another tensor does not fit.
void CopyFusionWeights(const FusionNet& from, FusionNet& to);

// Reads a file of SaveFusionNet into a float32 net. Throws Io (missing), ModelLoad (malformed,
// another kind, tensors that do not fit the stored widths).
FusionNet LoadFusionNet(const std::filesystem::path& path, FusionNetInfo* info = nullptr);

// What `fusion export` changes when it writes a trained net for shipping: the inference settings
// only (the weights stay as trained).
struct FusionExportOptions {
  double turn_open = -1.0;     // FusionNetOptions::turn_open (< 0 = as stored)
  bool keep_eye_mouth = false;  // turn FusionNetOptions::keep_eye_mouth on (false = as stored)
  bool keep_face = false;       // turn FusionNetOptions::keep_face on (false = as stored)
  bool half_precision = true;  // float16 weights (the shipped form)
  // Throws InvalidOptions for a turn_open above 1 or not finite.
  void Validate() const;
};
// Reads `from` (LoadFusionNet), applies `options` and writes the net to `to` atomically, keeping
// its step and provenance. Returns what the written file says about itself. Throws like
// LoadFusionNet and SaveFusionNet, InvalidOptions (a setting the stored net cannot take, e.g.
// turn_open without the turn input).
FusionNetInfo ExportFusionNet(const std::filesystem::path& from, const std::filesystem::path& to,
                              const FusionExportOptions& options);

}  // namespace avatar
