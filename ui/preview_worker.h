#pragma once
// Renders the viewport on its own thread and coalesces requests: while a frame renders,
// newer requests replace each other, so only the latest camera/expression/driver state is
// rendered next. What a change recomputes: a camera change renders the whole frame; an
// expression change at an unchanged view first shows the source's quick frame (the photo's face
// at the new expression over the last network frame: no network call) and then the full frame,
// which a newer request pre-empts. It renders whatever frame source the window gives it (the portrait, the
// morphable preview or the neural session). It also owns the driving video (a DrivingVideo,
// the same seekable driver every export reads): decoding and analysing driver frames happens
// here, never on the GUI thread. What is rendered is composed by ComposeFrame, as in exports.

#include <QImage>
#include <QObject>
#include <QString>
#include <QThread>

#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>

#include "core/pipeline/driving.h"
#include "core/pipeline/frame_source.h"

namespace avatar {
struct HeadMesh;
}

namespace avatar::ui {

// The viewport's meshes of one source (DetailFrameSource::ViewportMesh).
using ScenePtr = std::shared_ptr<const HeadMesh>;

// One viewport request.
struct PreviewRequest {
  // The user's view (an offset from the source's own pose; its zoom is the frame's zoom),
  // the user's expression controls and the size. The worker composes the rendered camera and
  // expression from it, the source's pose and the driver's sample (ComposeFrame).
  FrameRequest frame;
  int64_t driver_frame = -1;  // Driver frame to apply (-1 = none).
  bool driver_pose = false;   // Apply the driver's head pose (else only its expression).
};

// One finished viewport frame.
struct PreviewFrame {
  QImage image;         // RGB888, the rendered colour on black.
  QImage alpha;         // Grayscale8 opacity.
  QImage driver_image;  // The driver's video frame (RGB888), null without a driver.
  int64_t driver_frame = -1;
  bool driver_face_found = true;
  std::vector<QPointF> landmarks;  // Output pixels.
  std::vector<QPointF> vertices;   // Output pixels.
  std::vector<cv::Vec3i> triangles;
  double milliseconds = 0.0;  // Render time of this frame (driver analysis included).
  quint64 serial = 0;         // Serial of the request it answers.
  // What ran: "" = the full frame; "face update" = a quick frame (FrameSource::RenderQuick),
  // followed by the full frame of the same serial unless a newer request came first.
  QString stages;
};

class PreviewWorker : public QObject {
  Q_OBJECT

 public:
  explicit PreviewWorker(QObject* parent = nullptr);
  ~PreviewWorker() override;  // Stops the thread after the current frame.

  // Replaces the frame source (null = nothing to render). Thread: GUI.
  void setSource(std::shared_ptr<const FrameSource> source);
  std::shared_ptr<const FrameSource> source() const;

  // Sets the analyser factory used for driving videos (null = timing only).
  void setAnalyzerFactory(FrameAnalyzerFactory factory);
  // Opens a driving video on the worker thread; answers with driverLoaded or driverFailed.
  void loadDriver(const QString& path, const DrivingOptions& options);
  // Changes relative/absolute, the neutral frame or smoothing of the loaded driver.
  void setDrivingOptions(const DrivingOptions& options);
  void unloadDriver();

  // Builds the viewport's meshes of `source` on the worker thread when it has the detail path
  // (DetailFrameSource::ViewportMesh of it or of a source it wraps) and answers with sceneReady;
  // nothing for other sources. A failure is logged and leaves the viewport on rendered frames.
  void buildScene(std::shared_ptr<const FrameSource> source);

  // Queues a render of `request`; returns its serial. Older queued requests are dropped.
  quint64 request(const PreviewRequest& request);

  // Counters for tests and the status bar.
  quint64 requestsReceived() const { return requests_; }
  quint64 framesRendered() const { return rendered_; }
  // Quick frames shown before their full frame (an expression change at an unchanged view).
  quint64 quickFrames() const { return quick_; }
  bool isIdle() const;

 signals:
  void frameReady(const avatar::ui::PreviewFrame& frame);
  void renderFailed(const QString& message);
  void driverLoaded(const QString& path, qint64 frames, double fps, bool measured, bool has_audio);
  void driverFailed(const QString& path, const QString& message);
  // After a driver loads (before driverLoaded) and after its options change: the neutral
  // frame in use (-1: none) and, when it replaced a requested frame without a face, the
  // sentence saying so ("" otherwise).
  void drivingNeutralChosen(qint64 frame, const QString& note);
  // The meshes of the source `source_key` (the FrameSource's address given to buildScene).
  void sceneReady(quintptr source_key, avatar::ui::ScenePtr scene);

 private:
  struct DriverState;
  void drain();  // Worker thread.
  PreviewFrame renderOne(const PreviewRequest& request, const std::shared_ptr<const FrameSource>& source);
  // The source's quick frame of an undriven request, when it has one.
  std::optional<PreviewFrame> renderQuick(const PreviewRequest& request,
                                          const std::shared_ptr<const FrameSource>& source);

  QThread thread_;
  QObject* worker_ = nullptr;  // Lives on thread_.
  mutable std::mutex mutex_;
  std::optional<PreviewRequest> pending_;
  quint64 pending_serial_ = 0;
  bool scheduled_ = false;
  bool rendering_ = false;
  std::shared_ptr<const FrameSource> source_;
  FrameAnalyzerFactory analyzers_;
  std::unique_ptr<DriverState> driver_;  // Touched on the worker thread only.
  quint64 next_serial_ = 1;
  std::atomic<quint64> requests_{0};
  std::atomic<quint64> rendered_{0};
  std::atomic<quint64> quick_{0};
};

}  // namespace avatar::ui

Q_DECLARE_METATYPE(avatar::ui::PreviewFrame)
Q_DECLARE_METATYPE(avatar::ui::ScenePtr)
