#pragma once
// Minimal thread-safe logging with a forwarding hook (the GUI shows log lines in its
// status bar; tests capture them). Usage: AVATAR_LOG(kInfo) << "loaded " << path;

#include <functional>
#include <sstream>
#include <string>

namespace avatar {

enum class LogLevel { kDebug = 0, kInfo = 1, kWarning = 2, kError = 3 };

const char* LogLevelName(LogLevel level);

// Receives every emitted line (already filtered by level). Must be thread-safe.
using LogSink = std::function<void(LogLevel level, const std::string& message)>;

// Replaces the sink; an empty function restores the default (stderr). Returns the previous sink.
LogSink SetLogSink(LogSink sink);
// Lines below `level` are dropped. Default kInfo; env AVATAR_LOG_LEVEL=debug|info|warning|error.
void SetLogLevel(LogLevel level);
LogLevel GetLogLevel();
void EmitLog(LogLevel level, const std::string& message);

// Accumulates one line and emits it on destruction.
class LogLine {
 public:
  explicit LogLine(LogLevel level) : level_(level) {}
  LogLine(const LogLine&) = delete;
  LogLine& operator=(const LogLine&) = delete;
  ~LogLine() { EmitLog(level_, stream_.str()); }
  template <typename T>
  LogLine& operator<<(const T& value) {
    stream_ << value;
    return *this;
  }

 private:
  LogLevel level_;
  std::ostringstream stream_;
};

}  // namespace avatar

#define AVATAR_LOG(level)                                        \
  if (::avatar::LogLevel::level < ::avatar::GetLogLevel()) {     \
  } else                                                         \
    ::avatar::LogLine(::avatar::LogLevel::level)
