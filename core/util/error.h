#pragma once
// Typed errors of the core library. The library never aborts: every failure is
// one of these exceptions, and the message says what went wrong and what to do.

#include <sstream>
#include <stdexcept>
#include <string>
#include <type_traits>

namespace avatar {

// Base of every error the core throws on purpose.
class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& message) : std::runtime_error(message) {}
  // Short machine-readable category, e.g. "invalid_input".
  virtual const char* Kind() const noexcept { return "error"; }
};

#define AVATAR_DECLARE_ERROR(Name, kind)                                  \
  class Name : public Error {                                             \
   public:                                                                \
    explicit Name(const std::string& message) : Error(message) {}        \
    const char* Kind() const noexcept override { return kind; }           \
  }

// The user's data is unusable (no face found, unreadable image, empty video...).
AVATAR_DECLARE_ERROR(InvalidInput, "invalid_input");
// An option struct failed Validate() or a flag could not be parsed.
AVATAR_DECLARE_ERROR(InvalidOptions, "invalid_options");
// Reading or writing a file failed (missing, permission, disk full...).
AVATAR_DECLARE_ERROR(Io, "io");
// A model or checkpoint file is missing, truncated, foreign or inconsistent.
AVATAR_DECLARE_ERROR(ModelLoad, "model_load");
// Packaged data (models, samples) is not installed; the message says how to get it.
AVATAR_DECLARE_ERROR(MissingData, "missing_data");
// The user cancelled a long operation through RunContext.
AVATAR_DECLARE_ERROR(Cancelled, "cancelled");
// A broken internal invariant: a bug in Avatar Studio, never the user's fault.
AVATAR_DECLARE_ERROR(InternalError, "internal");

#undef AVATAR_DECLARE_ERROR

namespace internal {

// Collects a streamed message and throws E when the full expression ends.
template <typename E>
class CheckFailure {
 public:
  CheckFailure(const char* file, int line, const char* condition) {
    if (std::is_same<E, InternalError>::value) {
      stream_ << "check failed at " << file << ":" << line << ": " << condition << ". ";
    }
  }
  CheckFailure(const CheckFailure&) = delete;
  CheckFailure& operator=(const CheckFailure&) = delete;
  ~CheckFailure() noexcept(false) { throw E(stream_.str()); }

  template <typename T>
  CheckFailure& operator<<(const T& value) {
    stream_ << value;
    return *this;
  }

 private:
  std::ostringstream stream_;
};

}  // namespace internal

// Must be called inside a catch block. Rethrows the current exception as an avatar::Error:
// avatar errors pass through unchanged; LibTorch (c10::Error), OpenCV (cv::Exception) and
// allocation failures become InternalError / InvalidInput with `context` (e.g. the file
// being processed) in front of the message, so that callers only ever see our hierarchy.
[[noreturn]] void RethrowAsAvatarError(const std::string& context);

}  // namespace avatar

// AVATAR_CHECK_AS(Type, cond) << "message"; throws avatar::Type with the message when cond is false.
#define AVATAR_CHECK_AS(ErrorType, cond) \
  if (cond) {                            \
  } else                                 \
    ::avatar::internal::CheckFailure<::avatar::ErrorType>(__FILE__, __LINE__, #cond)

// AVATAR_CHECK(cond) << "message"; an internal invariant (throws InternalError with file:line).
#define AVATAR_CHECK(cond) AVATAR_CHECK_AS(InternalError, cond)
// Input validation (throws InvalidInput) and option validation (throws InvalidOptions).
#define AVATAR_CHECK_INPUT(cond) AVATAR_CHECK_AS(InvalidInput, cond)
#define AVATAR_CHECK_OPTION(cond) AVATAR_CHECK_AS(InvalidOptions, cond)
