#include "core/util/error.h"

#include <c10/util/Exception.h>
#include <opencv2/core.hpp>

#include <new>

namespace avatar {

void RethrowAsAvatarError(const std::string& context) {
  const std::string prefix = context.empty() ? std::string() : context + ": ";
  try {
    throw;
  } catch (const Error&) {
    throw;
  } catch (const c10::Error& e) {
    // LibTorch messages carry a long C++ backtrace; the first line is the useful part.
    std::string what = e.what_without_backtrace();
    throw InternalError(prefix + "tensor operation failed: " + what);
  } catch (const cv::Exception& e) {
    throw InvalidInput(prefix + "image operation failed: " + e.err);
  } catch (const std::bad_alloc&) {
    throw InternalError(prefix + "out of memory; try a smaller network size (--config) or close other programs");
  } catch (const std::exception& e) {
    throw InternalError(prefix + e.what());
  }
}

}  // namespace avatar
