#pragma once
// The studio's main window: the viewport in the middle; the source panel (portrait
// thumbnail with detection/landmarks, network size, quality, Reconstruct) on the left; pose and expression
// panels on the right; the driving panel (video, play/pause, timeline, neutral frame,
// transfer mode, smoothing) at the bottom; a status bar with the last frame time, the network
// size and the progress/cancel of the running job. Drag and drop: an image loads and reconstructs,
// a video becomes the driver. Long jobs (reconstruction, export) run on the JobRunner; the
// viewport renders on the PreviewWorker. Settings persist in QSettings.

#include <QImage>
#include <QMainWindow>
#include <QStringList>

#include <atomic>
#include <memory>
#include <optional>

#include <opencv2/core.hpp>

#include "core/pipeline/animate.h"
#include "core/pipeline/frame_source.h"
#include "core/pipeline/quality.h"

class QAction;
class QLabel;
class QMenu;
class QProgressBar;
class QPushButton;
class QTimer;

namespace avatar::ui {

class DrivingPanel;
class ExpressionPanel;
class JobRunner;
class PosePanel;
class PreviewWorker;
class LiveWorker;
struct LiveFrame;
struct PreviewFrame;
class SourcePanel;
class Viewport;

class MainWindow : public QMainWindow {
  Q_OBJECT

 public:
  explicit MainWindow(QWidget* parent = nullptr);
  ~MainWindow() override;

  // Loads a portrait through the core's image loader, shows it, and (when `reconstruct`)
  // starts reconstruction. The single path of File > Open, recent files, drag and drop and
  // --open. On failure the error is shown (a dialog when dialogs are enabled, always in the
  // status bar) and false is returned.
  bool openPortrait(const QString& path, bool reconstruct = true);
  // Starts reconstruction of the loaded portrait on the job worker (false if busy/none).
  bool reconstruct();
  // The studio switch "Photo detail on the head": shows the detail path or the network render
  // alone, at once when the last reconstruction built the detail path.
  void applyDetailSwitch(bool on);
  // The studio switch "Learned finish": the detail path finished by the bundled fusion net or
  // the geometric composite, at once (the same network source, nothing reconstructed).
  void applyFinishSwitch(bool learned);
  // Whether opening a portrait (File > Open, recent files, drag and drop, --open) starts its
  // reconstruction at once: Avatar > Reconstruct on Open, kept in the settings (default on).
  // Off, the photo stays in the viewport until Reconstruct is chosen (useful with the slow
  // paper configuration).
  void setReconstructOnOpen(bool on);
  bool reconstructOnOpen() const;
  // Loads a driving video (decoded and analysed on the preview worker).
  void openDriver(const QString& path);
  // Starts an export of the current avatar with the loaded driver (if any).
  bool startExport(const ExportOptions& output, const AnimationPlan& plan);
  // Asks for export settings, then starts the export.
  void showExportDialog();
  // Cancels the running job (reconstruction or export), and a live session.
  void cancelJob();

  // Live driving (issue 34): the current avatar driven by `camera` (a device index, /dev/videoN,
  // or a video file played as a camera) at 256 px, with the driving panel's transfer options.
  // The camera's frames show in the driving panel, the avatar's in the viewport; sliders and the
  // driving video rest while it runs. False (with the reason shown) without an avatar or when
  // the camera does not open. Driving > Live from Camera asks for the camera.
  bool startLive(const QString& camera);
  // Ends the live session (no-op when none runs).
  void stopLive();
  bool isLive() const { return live_active_; }

  // The neural model checkpoint to use ("" = the installed or bundled default).
  void setCheckpoint(const QString& path);
  QString checkpoint() const { return checkpoint_; }
  // This machine's time estimates of the quality ladder for the current model (cached, or
  // measured by the first reconstruction with the model); nullopt before that.
  const std::optional<QualityEstimates>& qualityEstimates() const { return estimates_; }

  // Dialogs are on by default; tests switch them off so nothing blocks.
  void setDialogsEnabled(bool enabled) { dialogs_enabled_ = enabled; }

  Viewport* viewport() const { return viewport_; }
  SourcePanel* sourcePanel() const { return source_panel_; }
  PosePanel* posePanel() const { return pose_panel_; }
  ExpressionPanel* expressionPanel() const { return expression_panel_; }
  DrivingPanel* drivingPanel() const { return driving_panel_; }
  PreviewWorker* previewWorker() const { return preview_; }
  JobRunner* jobRunner() const { return jobs_; }
  QStringList recentFiles() const;
  // The message of the last error ("" after a success).
  QString lastError() const { return last_error_; }
  // The frame source the viewport renders (null before a portrait is loaded).
  std::shared_ptr<const FrameSource> frameSource() const { return source_; }
  // Orbit steps drawn by the viewport's OpenGL meshes instead of a rendered frame.
  quint64 meshOrbitFrames() const { return mesh_orbit_frames_; }
  // The last frame shown in the viewport.
  const QImage& lastFrame() const { return last_frame_; }
  const QImage& lastAlpha() const { return last_alpha_; }
  // Driver frame index of the last frame shown (-1 without a driver).
  qint64 lastDriverFrame() const { return last_driver_frame_; }
  // The status bar's message (e.g. which neutral frame a driver uses).
  QString statusText() const;
  // The status bar's frame field: what the last frame cost and which stages ran.
  QString frameTimeText() const;

 signals:
  void portraitLoaded(const QString& path);
  void portraitFailed(const QString& path, const QString& message);
  void reconstructionFinished();
  // The ladder's estimates changed (read from the cache or measured).
  void qualityEstimatesChanged();
  void reconstructionFailed(const QString& message);
  void driverLoaded(const QString& path);
  void driverFailed(const QString& path, const QString& message);
  // A viewport frame was shown (the full frame answering request `serial`).
  void frameShown(quint64 serial);
  // A quick frame was shown first (an expression change: the face at once, the full frame of
  // the same serial follows unless a newer request pre-empts it).
  void quickFrameShown(quint64 serial);
  void exportFinished(const QString& path, qint64 frames);
  void exportFailed(const QString& message);
  void exportCancelled();
  // A live frame was shown (its camera frame number).
  void liveFrameShown(qint64 capture_index);
  // The live session ended (summary: frames, fps, latency and why).
  void liveEnded(const QString& summary);

 protected:
  void dragEnterEvent(QDragEnterEvent* event) override;
  void dropEvent(QDropEvent* event) override;
  void closeEvent(QCloseEvent* event) override;

 private:
  void createPanels();
  void createMenus();
  void createStatusBar();
  void rebuildRecentMenu();
  void addRecentFile(const QString& path);
  void showOpenDialog();
  void showOpenDriverDialog();
  void showLiveDialog();
  void onLiveFrame(const LiveFrame& frame);
  void showAbout();
  void showError(const QString& title, const QString& message);
  void setFrameSource(std::shared_ptr<const FrameSource> source);
  void requestPreview();
  // An orbit step: redraws the avatar's meshes at the new view with OpenGL when the viewport has
  // them and nothing drives the head (no network call; the full frame follows when the drag
  // ends), else requests the frame. Returns whether the meshes drew it.
  bool redrawOrbit();
  void showNeutralInUse();
  void onFrame(const PreviewFrame& frame);
  void onJobStarted(const QString& title);
  void onJobProgress(const QString& stage, double fraction, const QString& message);
  void onJobEnded();
  void playTick();
  void stepDriver(int delta);
  void saveExpressionPreset();
  void loadExpressionPreset();
  BackendOptions backendOptions() const;
  // Shows the cached estimates of the model the current options select (without loading it).
  void showCachedQualityEstimates();

  Viewport* viewport_ = nullptr;
  SourcePanel* source_panel_ = nullptr;
  PosePanel* pose_panel_ = nullptr;
  ExpressionPanel* expression_panel_ = nullptr;
  DrivingPanel* driving_panel_ = nullptr;
  PreviewWorker* preview_ = nullptr;
  LiveWorker* live_ = nullptr;
  bool live_active_ = false;
  QAction* stop_live_action_ = nullptr;
  JobRunner* jobs_ = nullptr;
  QTimer* play_timer_ = nullptr;
  QMenu* recent_menu_ = nullptr;
  QLabel* status_label_ = nullptr;
  QLabel* frame_time_label_ = nullptr;
  QLabel* config_label_ = nullptr;
  QLabel* stage_label_ = nullptr;
  QProgressBar* progress_ = nullptr;
  QPushButton* cancel_button_ = nullptr;
  QAction* show_landmarks_ = nullptr;
  QAction* show_mesh_ = nullptr;
  QAction* reconstruct_on_open_ = nullptr;
  QAction* export_action_ = nullptr;
  QAction* reconstruct_action_ = nullptr;
  QAction* cancel_action_ = nullptr;

  QString portrait_path_;
  cv::Mat portrait_;                           // BGR8 of the loaded portrait.
  std::shared_ptr<const FrameSource> source_;  // What the viewport renders.
  std::shared_ptr<const FrameSource> built_;   // Written by the reconstruction job.
  // The detail path's source of the last reconstruction while the studio switch shows its base.
  std::shared_ptr<const FrameSource> with_detail_;
  QString export_output_;
  std::atomic<qint64> export_frames_{0};  // Written by the export job.
  quint64 last_request_ = 0;
  bool orbit_pending_ = false;
  quint64 mesh_orbit_frames_ = 0;  // a drag was drawn by the meshes; the full frame follows on release
  quint64 last_shown_ = 0;
  QImage last_frame_;
  QImage last_alpha_;
  qint64 last_driver_frame_ = -1;
  QString driving_note_;        // The driver's note on its neutral frame ("" = none).
  qint64 neutral_in_use_ = -1;  // The driver's neutral frame (-1 = none).
  bool loading_driver_ = false;
  QString last_error_;
  bool dialogs_enabled_ = true;
  QString checkpoint_;
  std::optional<QualityEstimates> estimates_;
  std::optional<QualityEstimates> measured_;  // Written by the reconstruction job.
};

// True if the file name looks like an image the studio opens (by extension).
bool IsImageFile(const QString& path);
// True if the file name looks like a driving video (by extension).
bool IsDriverVideoFile(const QString& path);

}  // namespace avatar::ui
