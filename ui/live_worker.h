#pragma once
// The studio's Live source (issue 34): the avatar driven by a camera, or by a video file played
// as one, on a thread of its own through core/pipeline/live.h's RunLive - the loop of
// `avatar-studio live`, with its tracking, automatic neutral reference, smoothing and
// newest-frame-wins dropping. Frames, notes (no face, face back, resolution change) and the end
// of the session reach the GUI thread as queued signals; the camera is opened by start(), so a
// missing camera is an immediate, clear error.

#include <QImage>
#include <QObject>
#include <QString>

#include <atomic>
#include <memory>
#include <string>
#include <thread>

#include "core/pipeline/driving.h"
#include "core/pipeline/frame_source.h"
#include "core/pipeline/live.h"
#include "core/util/run_context.h"

namespace avatar::ui {

// One frame of a live session as the window shows it.
struct LiveFrame {
  QImage image;          // RGB888 avatar frame
  QImage camera;         // RGB888 camera frame that drove it
  bool face_found = true;
  int64_t capture_index = -1;
  double latency_ms = 0.0, render_ms = 0.0;
  double fps = 0.0;      // delivered frames per second so far
};

class LiveWorker : public QObject {
  Q_OBJECT

 public:
  explicit LiveWorker(QObject* parent = nullptr);
  ~LiveWorker() override;  // Stops the session and waits for its thread.

  // Drives `source` from `camera` (a device index, /dev/videoN or a video file), analysing the
  // camera frames with an analyser from `analyzers`. Opens the camera here: throws InvalidInput
  // naming the camera (and the cameras found, or that there are none) when it does not open.
  // A running session is stopped first. Thread: GUI.
  void start(std::shared_ptr<const FrameSource> source, FrameAnalyzerFactory analyzers, const std::string& camera,
             const LiveOptions& options);
  // Cancels the session and waits for its thread (no signal is emitted after it returns).
  void stop();
  bool running() const { return thread_.joinable() && !finished_; }

 signals:
  void frameReady(const avatar::ui::LiveFrame& frame);
  void noteReady(const QString& text);
  // The session ended by itself (the video ended, the camera stopped, an error) or by stop():
  // a summary line (frames, fps, latency, why it ended).
  void ended(const QString& summary, bool failed);

 private:
  std::thread thread_;
  std::unique_ptr<RunContext> ctx_;
  std::atomic<bool> finished_{false};
};

}  // namespace avatar::ui

Q_DECLARE_METATYPE(avatar::ui::LiveFrame)
