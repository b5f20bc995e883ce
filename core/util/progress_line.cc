#include "core/util/progress_line.h"

#include <unistd.h>

#include <cstdio>
#include <iostream>

namespace avatar {

ProgressLine::ProgressLine(std::ostream& out, bool terminal, double interval_seconds)
    : out_(&out), terminal_(terminal), interval_(interval_seconds) {}

ProgressLine ProgressLine::ForStderr(double interval_seconds) {
  return ProgressLine(std::cerr, ::isatty(::fileno(stderr)) == 1, interval_seconds);
}

void ProgressLine::Update(const std::string& text) {
  if (terminal_) {
    // Spaces over what is left of a longer previous line.
    const std::string pad = drawn_ > text.size() ? std::string(drawn_ - text.size(), ' ') : std::string();
    *out_ << '\r' << text << pad << std::flush;
    drawn_ = text.size();
    open_ = true;
    return;
  }
  const Clock::time_point now = Clock::now();
  if (!started_ || std::chrono::duration<double>(now - last_write_).count() >= interval_) {
    *out_ << text << '\n' << std::flush;
    last_write_ = now;
    started_ = true;
    pending_.clear();
  } else {
    pending_ = text;
  }
}

void ProgressLine::Finish() {
  if (terminal_) {
    if (open_) *out_ << '\n' << std::flush;
    open_ = false;
    drawn_ = 0;
    return;
  }
  if (!pending_.empty()) *out_ << pending_ << '\n' << std::flush;
  pending_.clear();
}

}  // namespace avatar
