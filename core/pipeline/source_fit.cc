#include "core/pipeline/source_fit.h"

#include <map>
#include <mutex>

namespace avatar {
namespace {

std::map<std::string, ExpressionSourceLoader>& Loaders() {
  static std::map<std::string, ExpressionSourceLoader> loaders;
  return loaders;
}
std::mutex& LoadersMutex() {
  static std::mutex m;
  return m;
}

}  // namespace

bool RegisterExpressionSourceLoader(const std::string& kind, ExpressionSourceLoader loader) {
  std::lock_guard<std::mutex> lock(LoadersMutex());
  Loaders()[kind] = loader;
  return true;
}

ExpressionSourceLoader FindExpressionSourceLoader(const std::string& kind) {
  std::lock_guard<std::mutex> lock(LoadersMutex());
  auto it = Loaders().find(kind);
  return it == Loaders().end() ? nullptr : it->second;
}

}  // namespace avatar
