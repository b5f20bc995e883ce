#pragma once
// Reading a built dataset's per-frame records (records.json, dataset_build.h) back into the
// pipeline's types: the morphable fit a record was made with and the stored aligned portrait, so
// that tools (evaluation, the fusion set) start from the data factory's one analysis of a frame
// instead of analysing it again.

#include <cstdint>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "core/face/face_types.h"
#include "core/morphable/morphable.h"

namespace avatar {

// A record's camera label ("label": 25 floats). Throws InvalidInput naming `what`.
morphable::CameraLabel RecordLabel(const nlohmann::json& values, const std::string& what);

// The fit of a record (alpha, beta, scale, label) for an image of `image_size` (the stored crop's).
// Throws InvalidInput naming the record for missing or malformed fields.
morphable::FitResult RecordFit(const nlohmann::json& record, cv::Size image_size);

// The stored aligned portrait of a record in dataset folder `dir`: the unmatted crop, the matte
// and the eye/mouth mask (files listed in the record). The matted crop is left empty
// (AnalysisFromFit makes it). Throws Io / InvalidInput naming the file.
face::AlignedPortrait RecordPortrait(const std::filesystem::path& dir, const nlohmann::json& record);

// The records of one split's pairs: a built dataset's shard holds the pairs.json entries whose two
// frames are in the split, in file order (dataset_build_finish.cc), so pair i of the shard is
// pairs[i] here. `ok` false with `why` when the folder has no records / pairs files or they list
// another number of pairs than `expected_pairs` (the shard's); throws InvalidInput for files that
// are not JSON arrays.
struct SplitPairRecords {
  bool ok = false;
  std::string why;                               // when !ok
  std::vector<std::pair<size_t, size_t>> pairs;  // (source, target) indices into records
  nlohmann::json records;
};
SplitPairRecords LoadSplitPairRecords(const std::filesystem::path& dir, const std::string& split,
                                      int64_t expected_pairs);

}  // namespace avatar
