#include "core/pipeline/session_access.h"

#include "core/pipeline/avatar_state.h"
#include "core/io/image_tensor.h"
#include "core/pipeline/session_impl.h"
#include "core/util/error.h"

namespace avatar {

GohaModel SessionAccess::Model(const Session& session) { return session.impl_->model; }

void SessionAccess::CheckAvatar(const Session& session, const Avatar& avatar) {
  AVATAR_CHECK_INPUT(avatar.valid()) << "refinement needs a reconstructed or loaded avatar";
  AVATAR_CHECK_INPUT(avatar.state_->model_id == session.impl_->info.model_id)
      << "this avatar was made with model '" << avatar.state_->model_id << "', the session runs '"
      << session.impl_->info.model_id << "'; reconstruct it again with this model";
}

torch::Tensor SessionAccess::Canonical(const Avatar& avatar) {
  AVATAR_CHECK_INPUT(avatar.valid()) << "empty avatar";
  return avatar.state_->canonical;
}

torch::Tensor SessionAccess::Appearance(const Avatar& avatar) {
  AVATAR_CHECK_INPUT(avatar.valid()) << "empty avatar";
  return avatar.state_->appearance;
}

torch::Tensor SessionAccess::ExpressionPlanes(const Session& session, const Avatar& avatar,
                                              const Expression& expression) {
  CheckAvatar(session, avatar);
  const AvatarState& state = *avatar.state_;
  if (state.expressions == nullptr) return {};
  torch::NoGradGuard no_grad;
  return session.impl_->ExpressionPlanes(*state.expressions, expression, nullptr);
}

Avatar SessionAccess::WithPlanes(const Avatar& avatar, const torch::Tensor& canonical,
                                 const torch::Tensor& appearance, const std::string& refinement_json) {
  AVATAR_CHECK_INPUT(avatar.valid()) << "empty avatar";
  const AvatarState& old = *avatar.state_;
  for (const torch::Tensor* t : {&canonical, &appearance}) {
    AVATAR_CHECK_INPUT(t->defined() && t->sizes() == old.canonical.sizes())
        << "refined planes have shape " << (t->defined() ? t->sizes() : c10::IntArrayRef{}) << ", expected "
        << old.canonical.sizes();
    AVATAR_CHECK_INPUT(torch::isfinite(*t).all().item<bool>()) << "refined planes have non-finite values";
  }
  auto state = std::make_shared<AvatarState>(old);
  torch::NoGradGuard no_grad;
  state->canonical = canonical.detach().to(old.canonical.device(), torch::kFloat32).clone();
  state->appearance = appearance.detach().to(old.appearance.device(), torch::kFloat32).clone();
  state->base = state->canonical + state->appearance;
  state->refinement = refinement_json;
  state->id = NextAvatarId();
  Avatar out;
  out.state_ = state;
  return out;
}

torch::Tensor SessionAccess::ImageTensor(const cv::Mat& bgr, int size, const char* what) {
  return ImageToTensor(bgr, size, what);
}

torch::Tensor SessionAccess::MaskTensor(const cv::Mat& mask, int size, float fill, const char* what) {
  return MaskToTensor(mask, size, fill, what);
}

}  // namespace avatar
