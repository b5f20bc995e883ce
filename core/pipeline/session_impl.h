#pragma once
// Private to the session module (session.cc, session_access.cc): the state behind a Session - the
// network, its description and the LRU cache of summed planes per (avatar, expression).

#include <atomic>
#include <list>
#include <memory>
#include <mutex>
#include <string>
#include <utility>

#include <opencv2/core.hpp>
#include <torch/torch.h>

#include "core/model/goha_model.h"
#include "core/pipeline/avatar_state.h"
#include "core/io/image_tensor.h"
#include "core/pipeline/session.h"
#include "core/render/occupancy_grid.h"
#include "core/util/error.h"
#include "core/util/run_context.h"

namespace avatar {

struct Session::Impl {
  SessionOptions options;
  mutable GohaModel model{nullptr};  // forward passes only read parameters
  ModelInfo info;
  // Summed planes of one (avatar, expression) and their occupancy grid, built (once, under
  // `grid_mutex`) at the second frame that skips empty space with these planes: the first frame
  // of a new expression never waits for a grid, so a slider drag that changes the expression
  // every frame pays nothing for it, while an orbit or a held expression gets it from its second
  // frame on.
  struct CachedPlanes {
    torch::Tensor planes;
    std::mutex grid_mutex;
    int grid_requests = 0;
    std::shared_ptr<const render::OccupancyGrid> grid;
  };
  mutable std::mutex cache_mutex;
  // LRU of summed planes T_c + T_p + T_e keyed by "<avatar id>|<expression key>". A new
  // reconstruction or a refinement makes a new avatar id, so its planes and grid are new entries.
  mutable std::list<std::pair<std::string, std::shared_ptr<CachedPlanes>>> cache;
  mutable std::atomic<int64_t> expression_images{0};

  // T_e [1,3,C,P,P] of `expression`, the one path of frames and refinement: E_e over the I_exp
  // that `source` renders, or, for a network with expression bases, the bases mixed by the
  // expression's morphable coefficients (the beta that I_exp shows).
  torch::Tensor ExpressionPlanes(const ExpressionImageSource& source, const Expression& expression,
                                 RunContext* ctx) const {
    if (model->config().expression_bases()) {
      const std::vector<float> beta = source.Coefficients(expression);
      AVATAR_CHECK_INPUT(!beta.empty()) << "the model's expression planes come from morphable expression coefficients "
                                           "(expression_model bases), and this avatar's expression source ("
                                        << source.Kind() << ") has none; reconstruct the avatar from a photo";
      if (ctx != nullptr) ctx->Report("animate", 0.2, "expression planes");
      return model->ExpressionPlanesFromCoefficients(torch::tensor(beta, torch::kFloat32).unsqueeze(0));
    }
    const int s = model->config().image_size;
    if (ctx != nullptr) ctx->Report("animate", 0.1, "expression image");
    const cv::Mat exp_image = source.Render(expression, s);
    ++expression_images;
    AVATAR_CHECK(exp_image.type() == CV_8UC3 && exp_image.rows == s && exp_image.cols == s)
        << "expression source returned a " << exp_image.cols << "x" << exp_image.rows << " image, expected " << s;
    if (ctx != nullptr) ctx->Report("animate", 0.2, "expression planes");
    return model->ExpressionPlanes(ImageToTensor(exp_image, s, "I_exp"));
  }

  // The entry's grid, or null at its first request (see CachedPlanes).
  std::shared_ptr<const render::OccupancyGrid> GridFor(CachedPlanes& entry) const {
    std::lock_guard<std::mutex> lock(entry.grid_mutex);
    if (entry.grid == nullptr && ++entry.grid_requests >= 2) entry.grid = model->OccupancyGridFor(entry.planes);
    return entry.grid;
  }

  std::shared_ptr<CachedPlanes> PlanesFor(const AvatarState& state, const Expression& expression,
                                          RunContext* ctx) const {
    const std::string key = std::to_string(state.id) + "|" + expression.Key();
    {
      std::lock_guard<std::mutex> lock(cache_mutex);
      for (auto it = cache.begin(); it != cache.end(); ++it) {
        if (it->first == key) {
          cache.splice(cache.begin(), cache, it);
          return cache.front().second;
        }
      }
    }
    AVATAR_CHECK_INPUT(state.expressions != nullptr) << "this avatar has no expression source";
    auto entry = std::make_shared<CachedPlanes>();
    entry->planes = state.base + ExpressionPlanes(*state.expressions, expression, ctx);
    std::lock_guard<std::mutex> lock(cache_mutex);
    cache.emplace_front(key, entry);
    while (static_cast<int>(cache.size()) > options.expression_cache) cache.pop_back();
    return entry;
  }
};

}  // namespace avatar
