#pragma once
// One progress line for long commands (dataset build, train, eval). On a terminal it is redrawn
// in place ("\r"); in a log file or pipe (CI, `> run.stdout 2>&1`) each update would otherwise
// pile up on one endless line, so there it becomes a normal line at most every few seconds,
// plus the last state when the work ends.

#include <chrono>
#include <iosfwd>
#include <string>

namespace avatar {

class ProgressLine {
 public:
  // `terminal`: redraw in place; else one line per `interval_seconds` (the first update and
  // the one before Finish() are always written).
  ProgressLine(std::ostream& out, bool terminal, double interval_seconds = 30.0);
  // Writes to std::cerr, redrawing when stderr is a terminal.
  static ProgressLine ForStderr(double interval_seconds = 30.0);

  // The current state (no line break inside).
  void Update(const std::string& text);
  // Ends the line: on a terminal a line break; elsewhere the last state if it was not written.
  // Safe to call more than once.
  void Finish();

 private:
  using Clock = std::chrono::steady_clock;
  std::ostream* out_;
  bool terminal_;
  double interval_;
  std::string pending_;  // Last text not yet written (log mode).
  size_t drawn_ = 0;     // Length of the line on screen (terminal mode).
  bool started_ = false;
  bool open_ = false;    // Something was drawn since the last Finish().
  Clock::time_point last_write_{};
};

}  // namespace avatar
