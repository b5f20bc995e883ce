// LibTorch headers (through the pipeline) first: Qt's `slots` keyword macro breaks them when it is defined earlier.
#include "core/pipeline/detail_source.h"

#include "ui/main_window.h"

#include <QAction>
#include <QCheckBox>
#include <QApplication>
#include <QCloseEvent>
#include <QDockWidget>
#include <QDragEnterEvent>
#include <QDropEvent>
#include <QElapsedTimer>
#include <QFileDialog>
#include <QFileInfo>
#include <QInputDialog>
#include <QLabel>
#include <QMenu>
#include <QMenuBar>
#include <QMessageBox>
#include <QMimeData>
#include <QProgressBar>
#include <QPushButton>
#include <QScrollArea>
#include <QSettings>
#include <QSlider>
#include <QStatusBar>
#include <QTimer>
#include <QVBoxLayout>

#include "core/io/image_io.h"
#include "core/io/video_io.h"
#include "core/pipeline/live.h"
#include "core/pipeline/session_source.h"
#include "core/pipeline/studio_backend.h"
#include "core/util/error.h"
#include "core/util/logging.h"
#include "core/util/version.h"
#include "ui/export_dialog.h"
#include "ui/image_convert.h"
#include "ui/job_runner.h"
#include "ui/live_worker.h"
#include "ui/panels.h"
#include "ui/preview_worker.h"
#include "ui/viewport.h"

namespace avatar::ui {
namespace {

constexpr int kMaxRecentFiles = 8;
constexpr int kPreviewSize = 512;  // Viewport frames are rendered at this size.
const char* const kRecentKey = "recentFiles";
const char* const kGeometryKey = "mainWindow/geometry";
const char* const kStateKey = "mainWindow/state";
const QString kReconstructTitle = QStringLiteral("Reconstruct");
const QString kExportTitle = QStringLiteral("Export");

QString LocalFileFromMime(const QMimeData* mime) {
  if (mime == nullptr || !mime->hasUrls()) return {};
  for (const QUrl& url : mime->urls()) {
    if (!url.isLocalFile()) continue;
    const QString f = url.toLocalFile();
    if (IsImageFile(f) || IsDriverVideoFile(f)) return f;
  }
  return {};
}

// "the neutral frame ..." -> "The neutral frame ..." for the status bar.
QString SentenceCase(const QString& text) {
  if (text.isEmpty()) return text;
  return text.left(1).toUpper() + text.mid(1);
}

}  // namespace

bool IsImageFile(const QString& path) {
  static const QStringList kExtensions = {"jpg", "jpeg", "png", "bmp", "tif", "tiff", "webp"};
  return kExtensions.contains(QFileInfo(path).suffix().toLower());
}

bool IsDriverVideoFile(const QString& path) { return IsVideoPath(path.toStdString()); }

MainWindow::MainWindow(QWidget* parent) : QMainWindow(parent) {
  setWindowTitle(QStringLiteral("Avatar Studio"));
  setAcceptDrops(true);
  setDockOptions(QMainWindow::AnimatedDocks | QMainWindow::AllowTabbedDocks);
  viewport_ = new Viewport(this);
  setCentralWidget(viewport_);
  preview_ = new PreviewWorker(this);
  live_ = new LiveWorker(this);
  connect(live_, &LiveWorker::frameReady, this, &MainWindow::onLiveFrame);
  connect(live_, &LiveWorker::noteReady, this, [this](const QString& note) {
    if (live_active_) status_label_->setText(tr("Live: %1").arg(note));
  });
  connect(live_, &LiveWorker::ended, this, [this](const QString& summary, bool failed) {
    const bool was_active = live_active_;
    live_active_ = false;
    stop_live_action_->setEnabled(false);
    if (failed) {
      showError(tr("Live"), summary);
    } else {
      status_label_->setText(summary);
    }
    if (was_active || failed) requestPreview();  // the sliders' frame again
    emit liveEnded(summary);
  });
  jobs_ = new JobRunner(this);
  play_timer_ = new QTimer(this);
  createPanels();
  createStatusBar();
  createMenus();

  connect(preview_, &PreviewWorker::frameReady, this, &MainWindow::onFrame);
  connect(preview_, &PreviewWorker::renderFailed, this,
          [this](const QString& m) { status_label_->setText(tr("Render failed: %1").arg(m)); });
  connect(preview_, &PreviewWorker::drivingNeutralChosen, this, [this](qint64 frame, const QString& note) {
    driving_note_ = note;
    neutral_in_use_ = frame;
    if (loading_driver_) return;  // driverLoaded shows both.
    showNeutralInUse();
    if (!note.isEmpty()) status_label_->setText(SentenceCase(note));
  });
  connect(preview_, &PreviewWorker::driverLoaded, this,
          [this](const QString& path, qint64 frames, double fps, bool measured, bool has_audio) {
            loading_driver_ = false;
            driving_panel_->setDriver(path, frames, fps, measured, has_audio);
            showNeutralInUse();
            QString status = tr("Driving video %1 loaded").arg(QFileInfo(path).fileName());
            if (!driving_note_.isEmpty()) status += QStringLiteral("; ") + driving_note_;
            status_label_->setText(status);
            emit driverLoaded(path);
            requestPreview();
          });
  connect(preview_, &PreviewWorker::driverFailed, this, [this](const QString& path, const QString& message) {
    loading_driver_ = false;
    showError(tr("Could not load the driving video"), message);
    emit driverFailed(path, message);
  });
  connect(viewport_, &Viewport::orbitDragged, this, [this](double dyaw, double dpitch) {
    ViewPose p = pose_panel_->pose();
    p.yaw += dyaw;
    p.pitch += dpitch;
    pose_panel_->setPose(p);
    if (!redrawOrbit()) requestPreview();
  });
  connect(viewport_, &Viewport::orbitFinished, this, [this] {
    if (orbit_pending_) requestPreview();  // the full frame of where the drag stopped
  });
  connect(preview_, &PreviewWorker::sceneReady, this, [this](quintptr key, ScenePtr scene) {
    if (!source_ || reinterpret_cast<quintptr>(source_.get()) != key) return;  // a replaced source's
    viewport_->setScene(std::move(scene));
  });
  // A zoom step or a reset: the meshes at once where the viewport has them, the full frame next.
  connect(viewport_, &Viewport::zoomWheeled, this, [this](double factor) {
    ViewPose p = pose_panel_->pose();
    p.zoom *= factor;
    pose_panel_->setPose(p);
    redrawOrbit();
    requestPreview();
  });
  connect(viewport_, &Viewport::resetRequested, this, [this] {
    pose_panel_->setPose({});
    redrawOrbit();
    requestPreview();
  });
  connect(jobs_, &JobRunner::started, this, &MainWindow::onJobStarted);
  connect(jobs_, &JobRunner::progress, this, &MainWindow::onJobProgress);
  connect(jobs_, &JobRunner::finished, this, [this](const QString& title) {
    onJobEnded();
    if (title == kReconstructTitle) {
      with_detail_.reset();
      setFrameSource(built_);
      built_.reset();
      if (measured_) {
        estimates_ = measured_;
        measured_.reset();
        source_panel_->setQualityEstimates(estimates_);
        emit qualityEstimatesChanged();
      }
      QString done = tr("Reconstructed %1").arg(QFileInfo(portrait_path_).fileName());
      if (source_) {
        for (const std::string& w : source_->Warnings()) done += tr(". Warning: %1").arg(QString::fromStdString(w));
      }
      status_label_->setText(done);
      emit reconstructionFinished();
    } else if (title == kExportTitle) {
      status_label_->setText(tr("Exported %1 frames to %2").arg(export_frames_.load()).arg(export_output_));
      emit exportFinished(export_output_, export_frames_.load());
    }
  });
  connect(jobs_, &JobRunner::failed, this, [this](const QString& title, const QString& message) {
    onJobEnded();
    if (title == kReconstructTitle) {
      showError(tr("Reconstruction failed"), message);
      emit reconstructionFailed(message);
    } else {
      showError(tr("Export failed"), message);
      emit exportFailed(message);
    }
  });
  connect(jobs_, &JobRunner::cancelled, this, [this](const QString& title) {
    onJobEnded();
    status_label_->setText(tr("%1 cancelled").arg(title));
    if (title == kExportTitle) emit exportCancelled();
  });
  connect(play_timer_, &QTimer::timeout, this, &MainWindow::playTick);

  QSettings settings;
  if (!restoreGeometry(settings.value(kGeometryKey).toByteArray())) resize(1280, 720);
  restoreState(settings.value(kStateKey).toByteArray());
  preview_->setAnalyzerFactory(DrivingAnalyzers(backendOptions()));
  showCachedQualityEstimates();
}

MainWindow::~MainWindow() {
  // The workers reference the window's state through queued calls: stop them first.
  play_timer_->stop();
  delete jobs_;
  jobs_ = nullptr;
  delete preview_;
  preview_ = nullptr;
}

void MainWindow::createPanels() {
  source_panel_ = new SourcePanel(this);
  auto* source_dock = new QDockWidget(tr("Source"), this);
  source_dock->setObjectName(QStringLiteral("sourceDock"));
  source_dock->setWidget(source_panel_);
  source_dock->setFeatures(QDockWidget::DockWidgetMovable | QDockWidget::DockWidgetFloatable);
  addDockWidget(Qt::LeftDockWidgetArea, source_dock);
  connect(source_panel_, &SourcePanel::reconstructRequested, this, &MainWindow::reconstruct);
  connect(source_panel_, &SourcePanel::configChanged, this, [this](const QString& config) {
    config_label_->setText(tr("Network size: %1").arg(config));
    showCachedQualityEstimates();
  });
  connect(source_panel_->randomWeightsBox(), &QCheckBox::toggled, this, [this] { showCachedQualityEstimates(); });
  connect(source_panel_, &SourcePanel::detailChanged, this, &MainWindow::applyDetailSwitch);
  connect(source_panel_, &SourcePanel::finishChanged, this, &MainWindow::applyFinishSwitch);
  connect(source_panel_, &SourcePanel::qualityChanged, this, [this](const QString& quality) {
    if (source_) status_label_->setText(tr("Quality %1 applies from the next reconstruction (Ctrl+R)").arg(quality));
  });

  auto* controls = new QWidget(this);
  auto* layout = new QVBoxLayout(controls);
  pose_panel_ = new PosePanel(controls);
  expression_panel_ = new ExpressionPanel(controls);
  auto* pose_title = new QLabel(tr("<b>Pose</b>"), controls);
  auto* expr_title = new QLabel(tr("<b>Expression</b>"), controls);
  layout->addWidget(pose_title);
  layout->addWidget(pose_panel_);
  layout->addWidget(expr_title);
  layout->addWidget(expression_panel_);
  layout->addStretch(1);
  auto* scroll = new QScrollArea(this);
  scroll->setWidget(controls);
  scroll->setWidgetResizable(true);
  scroll->setMinimumWidth(300);
  auto* controls_dock = new QDockWidget(tr("Pose and Expression"), this);
  controls_dock->setObjectName(QStringLiteral("controlsDock"));
  controls_dock->setWidget(scroll);
  controls_dock->setFeatures(QDockWidget::DockWidgetMovable | QDockWidget::DockWidgetFloatable);
  addDockWidget(Qt::RightDockWidgetArea, controls_dock);
  connect(pose_panel_, &PosePanel::poseChanged, this, [this] { requestPreview(); });
  connect(expression_panel_, &ExpressionPanel::expressionChanged, this, [this] { requestPreview(); });
  connect(expression_panel_, &ExpressionPanel::saveRequested, this, &MainWindow::saveExpressionPreset);
  connect(expression_panel_, &ExpressionPanel::loadRequested, this, &MainWindow::loadExpressionPreset);

  driving_panel_ = new DrivingPanel(this);
  auto* driving_dock = new QDockWidget(tr("Driving"), this);
  driving_dock->setObjectName(QStringLiteral("drivingDock"));
  driving_dock->setWidget(driving_panel_);
  driving_dock->setFeatures(QDockWidget::DockWidgetMovable | QDockWidget::DockWidgetFloatable);
  addDockWidget(Qt::BottomDockWidgetArea, driving_dock);
  connect(driving_panel_, &DrivingPanel::loadRequested, this, &MainWindow::showOpenDriverDialog);
  connect(driving_panel_, &DrivingPanel::unloadRequested, this, [this] {
    preview_->unloadDriver();
    driving_panel_->clearDriver();
    requestPreview();
  });
  connect(driving_panel_, &DrivingPanel::frameChanged, this, [this] { requestPreview(); });
  connect(driving_panel_, &DrivingPanel::followPoseChanged, this, [this] { requestPreview(); });
  connect(driving_panel_, &DrivingPanel::optionsChanged, this, [this](const DrivingOptions& o) {
    preview_->setDrivingOptions(o);
    requestPreview();
  });
  connect(driving_panel_, &DrivingPanel::playingChanged, this, [this](bool playing) {
    if (playing) {
      play_timer_->start(static_cast<int>(1000.0 / std::max(1.0, driving_panel_->fps())));
    } else {
      play_timer_->stop();
    }
  });
}

void MainWindow::createStatusBar() {
  status_label_ = new QLabel(tr("No portrait loaded"), this);
  status_label_->setToolTip(tr("What the studio is doing"));
  statusBar()->addWidget(status_label_, 1);
  stage_label_ = new QLabel(this);
  stage_label_->setToolTip(tr("Stage of the running job"));
  statusBar()->addPermanentWidget(stage_label_);
  progress_ = new QProgressBar(this);
  progress_->setRange(0, 1000);
  progress_->setMaximumWidth(180);
  progress_->setToolTip(tr("Progress of the running job"));
  progress_->setVisible(false);
  statusBar()->addPermanentWidget(progress_);
  cancel_button_ = new QPushButton(tr("Cancel"), this);
  cancel_button_->setToolTip(tr("Cancel the running job (Esc)"));
  cancel_button_->setVisible(false);
  connect(cancel_button_, &QPushButton::clicked, this, &MainWindow::cancelJob);
  statusBar()->addPermanentWidget(cancel_button_);
  frame_time_label_ = new QLabel(tr("Frame: -"), this);
  frame_time_label_->setToolTip(tr("Render time of the last viewport frame"));
  statusBar()->addPermanentWidget(frame_time_label_);
  config_label_ = new QLabel(tr("Network size: %1").arg(source_panel_->config()), this);
  config_label_->setObjectName(QStringLiteral("networkSizeLabel"));
  config_label_->setToolTip(tr("Network size of random weights (choose it in the source panel)"));
  statusBar()->addPermanentWidget(config_label_);
}

void MainWindow::createMenus() {
  QMenu* file = menuBar()->addMenu(tr("&File"));
  QAction* open = file->addAction(tr("&Open Portrait..."), this, &MainWindow::showOpenDialog);
  open->setShortcut(QKeySequence::Open);
  open->setToolTip(tr("Open a portrait photo (JPEG, PNG, ...)"));
  QAction* driver = file->addAction(tr("Open &Driving Video..."), this, &MainWindow::showOpenDriverDialog);
  driver->setShortcut(QKeySequence(Qt::CTRL | Qt::SHIFT | Qt::Key_O));
  driver->setToolTip(tr("Load a video whose expressions and head motion drive the avatar"));
  recent_menu_ = file->addMenu(tr("Open &Recent"));
  rebuildRecentMenu();
  file->addSeparator();
  export_action_ = file->addAction(tr("&Export Animation..."), this, &MainWindow::showExportDialog);
  export_action_->setShortcut(QKeySequence(Qt::CTRL | Qt::Key_E));
  export_action_->setToolTip(tr("Export an MP4 or a PNG sequence with alpha"));
  export_action_->setEnabled(false);
  file->addSeparator();
  QAction* quit = file->addAction(tr("&Quit"), this, &QWidget::close);
  quit->setShortcut(QKeySequence::Quit);

  QMenu* avatar = menuBar()->addMenu(tr("&Avatar"));
  reconstruct_action_ = avatar->addAction(tr("&Reconstruct"), this, &MainWindow::reconstruct);
  reconstruct_action_->setShortcut(QKeySequence(Qt::CTRL | Qt::Key_R));
  reconstruct_action_->setEnabled(false);
  reconstruct_on_open_ = avatar->addAction(tr("Reconstruct on &Open"));
  reconstruct_on_open_->setCheckable(true);
  reconstruct_on_open_->setChecked(QSettings().value("avatar/reconstruct_on_open", true).toBool());
  reconstruct_on_open_->setToolTip(tr("Start reconstruction as soon as a portrait is opened or dropped"));
  connect(reconstruct_on_open_, &QAction::toggled, this,
          [](bool on) { QSettings().setValue("avatar/reconstruct_on_open", on); });
  cancel_action_ = avatar->addAction(tr("&Cancel Job"), this, &MainWindow::cancelJob);
  cancel_action_->setShortcut(QKeySequence(Qt::Key_Escape));
  cancel_action_->setEnabled(false);
  avatar->addSeparator();
  QAction* neutral = avatar->addAction(tr("&Neutral Expression"), expression_panel_, &ExpressionPanel::resetToNeutral);
  neutral->setShortcut(QKeySequence(Qt::CTRL | Qt::Key_N));

  QMenu* view = menuBar()->addMenu(tr("&View"));
  QAction* reset = view->addAction(tr("&Reset View"), this, [this] {
    pose_panel_->setPose({});
    requestPreview();
  });
  reset->setShortcut(QKeySequence(Qt::CTRL | Qt::Key_0));
  QSettings settings;
  show_landmarks_ = view->addAction(tr("Show &Landmarks"));
  show_landmarks_->setCheckable(true);
  show_landmarks_->setShortcut(QKeySequence(Qt::CTRL | Qt::Key_L));
  show_landmarks_->setChecked(settings.value("view/landmarks", false).toBool());
  show_mesh_ = view->addAction(tr("Show &Mesh"));
  show_mesh_->setCheckable(true);
  show_mesh_->setShortcut(QKeySequence(Qt::CTRL | Qt::Key_M));
  show_mesh_->setChecked(settings.value("view/mesh", false).toBool());
  viewport_->setShowLandmarks(show_landmarks_->isChecked());
  viewport_->setShowMesh(show_mesh_->isChecked());
  connect(show_landmarks_, &QAction::toggled, this, [this](bool on) {
    viewport_->setShowLandmarks(on);
    QSettings().setValue("view/landmarks", on);
  });
  connect(show_mesh_, &QAction::toggled, this, [this](bool on) {
    viewport_->setShowMesh(on);
    QSettings().setValue("view/mesh", on);
  });

  QMenu* drive = menuBar()->addMenu(tr("&Driving"));
  QAction* play =
      drive->addAction(tr("&Play / Pause"), this, [this] { driving_panel_->setPlaying(!driving_panel_->isPlaying()); });
  play->setShortcut(QKeySequence(Qt::Key_Space));
  QAction* back = drive->addAction(tr("Step &Back"), this, [this] { stepDriver(-1); });
  back->setShortcut(QKeySequence(Qt::Key_BracketLeft));
  QAction* forward = drive->addAction(tr("Step &Forward"), this, [this] { stepDriver(1); });
  forward->setShortcut(QKeySequence(Qt::Key_BracketRight));
  drive->addSeparator();
  QAction* live = drive->addAction(tr("&Live from Camera..."), this, &MainWindow::showLiveDialog);
  live->setShortcut(QKeySequence(tr("Ctrl+Shift+L")));
  live->setToolTip(tr("Drive the avatar from a camera (or a video file played as one): head pose and expression "
                      "follow the face in front of it, relative to the first frame with a face"));
  stop_live_action_ = drive->addAction(tr("&Stop Live"), this, &MainWindow::stopLive);
  stop_live_action_->setToolTip(tr("End the live session (Esc does too)"));
  stop_live_action_->setEnabled(false);

  QMenu* help = menuBar()->addMenu(tr("&Help"));
  help->addAction(tr("&About Avatar Studio"), this, &MainWindow::showAbout);
  for (QMenu* m : {file, avatar, view, drive, help}) m->setToolTipsVisible(true);
}

BackendOptions MainWindow::backendOptions() const {
  BackendOptions o;
  o.config = source_panel_->config().toStdString();
  o.random_weights = source_panel_->randomWeights();
  o.renderer = source_panel_->morphablePreview() ? "morphable" : "neural";
  o.checkpoint = checkpoint_.toStdString();
  o.quality = source_panel_->quality().toStdString();
  o.detail = !source_panel_->photoDetail() ? "off" : source_panel_->learnedFinish() ? "head" : "geometric";
  return o;
}

void MainWindow::applyDetailSwitch(bool on) {
  if (!source_) return;
  // The detail path wraps the network's source: switching it off shows the wrapped source at
  // once, and switching it back on restores the wrapper kept from the last reconstruction.
  const std::shared_ptr<const FrameSource> inner = source_->Wrapped();
  if (!on && inner != nullptr) {
    with_detail_ = source_;
    setFrameSource(inner);
  } else if (on && with_detail_ != nullptr && with_detail_->Wrapped() == source_) {
    setFrameSource(with_detail_);
  } else if (on && inner == nullptr && dynamic_cast<const SessionFrameSource*>(source_.get()) != nullptr) {
    status_label_->setText(tr("The photo's detail applies from the next reconstruction (Ctrl+R)"));
  }
}

void MainWindow::applyFinishSwitch(bool learned) {
  // The detail source shown is rebuilt over the same network source with or without the fusion
  // net; nothing is reconstructed. (The switch is disabled while the detail is off.)
  BackendOptions o = backendOptions();
  o.detail = learned ? "head" : "geometric";
  std::string note;
  const std::string weights = FusionWeightsOf(o, &note);
  try {
    if (const auto* detail = dynamic_cast<const DetailFrameSource*>(source_.get()))
      setFrameSource(detail->WithFusion(weights));
  } catch (const std::exception& e) {
    showError(tr("Learned finish"), QString::fromUtf8(e.what()));
    return;
  }
  if (learned && weights.empty() && !note.empty()) status_label_->setText(QString::fromStdString(note));
}

void MainWindow::setCheckpoint(const QString& path) {
  checkpoint_ = path;
  showCachedQualityEstimates();
}

void MainWindow::showCachedQualityEstimates() {
  const BackendOptions b = backendOptions();
  SessionOptions so;
  so.checkpoint = b.checkpoint;
  so.random_weights = b.random_weights && b.checkpoint.empty();
  so.config = b.config;
  so.data_dir = b.data_dir;
  std::optional<QualityEstimates> cached;
  try {
    const std::filesystem::path cache = QualityCachePath(b.data_dir);
    const std::filesystem::path ckpt = ResolveCheckpoint(so);
    const int threads = QualityEstimateThreads();
    cached = ckpt.empty() ? ReadCachedQualityEstimates(cache, RandomModelId(so.config, so.seed), threads)
                          : ReadCachedQualityEstimatesForCheckpoint(cache, ckpt, threads);
  } catch (const std::exception&) {
    // No model found: the ladder says "not measured yet".
  }
  estimates_ = cached;
  source_panel_->setQualityEstimates(estimates_);
  emit qualityEstimatesChanged();
}

void MainWindow::showError(const QString& title, const QString& message) {
  last_error_ = message;
  status_label_->setText(tr("%1: %2").arg(title, message));
  if (dialogs_enabled_) QMessageBox::warning(this, title, message);
}

bool MainWindow::openPortrait(const QString& path, bool reconstruct_now) {
  try {
    const cv::Mat bgr = LoadImageBgr(path.toStdString());
    portrait_ = bgr;
    portrait_path_ = path;
    last_error_.clear();
    status_label_->setText(tr("%1  (%2 x %3)").arg(QFileInfo(path).fileName()).arg(bgr.cols).arg(bgr.rows));
    setWindowTitle(tr("%1 - Avatar Studio").arg(QFileInfo(path).fileName()));
    addRecentFile(QFileInfo(path).absoluteFilePath());
    source_panel_->setPortrait(ToQImage(bgr), {});
    reconstruct_action_->setEnabled(true);
    // Until reconstruction finishes the viewport shows the photo itself, labelled so.
    setFrameSource(std::make_shared<PortraitFrameSource>(bgr));
    emit portraitLoaded(path);
    if (reconstruct_now && reconstructOnOpen()) reconstruct();
    return true;
  } catch (const std::exception& e) {
    status_label_->setText(tr("Could not open %1").arg(QFileInfo(path).fileName()));
    showError(tr("Could not open the portrait"), QString::fromStdString(e.what()));
    emit portraitFailed(path, last_error_);
    return false;
  }
}

void MainWindow::setReconstructOnOpen(bool on) { reconstruct_on_open_->setChecked(on); }

bool MainWindow::reconstructOnOpen() const { return reconstruct_on_open_->isChecked(); }

bool MainWindow::reconstruct() {
  if (portrait_.empty() || jobs_->isBusy()) return false;
  const cv::Mat portrait = portrait_;
  const BackendOptions backend = backendOptions();
  preview_->setAnalyzerFactory(DrivingAnalyzers(backend));
  built_.reset();
  measured_.reset();
  const std::string name = QFileInfo(portrait_path_).fileName().toStdString();
  return jobs_->start(kReconstructTitle, [this, portrait, backend, name](RunContext& ctx) {
    // Runs on the job thread; built_ and measured_ are read on the GUI thread only after `finished`.
    const std::filesystem::path cache = QualityCachePath(backend.data_dir);
    std::shared_ptr<const Session> session;
    bool measure = false;
    if (backend.renderer == "neural" || backend.random_weights) {
      try {
        session = SharedSession(backend);
        measure = !ReadCachedQualityEstimates(cache, session->Info().model_id, QualityEstimateThreads());
      } catch (const Error&) {
        session.reset();  // CreateFrameSource reports (or falls back from) a model that does not load.
      }
    }
    try {
      RunContext::ProgressRange range(ctx, 0.0, measure ? 0.85 : 1.0);
      built_ = CreateFrameSource(portrait, backend, ctx);
    } catch (const InvalidInput& e) {
      throw InvalidInput(name + ": " + e.what());
    }
    if (session != nullptr && dynamic_cast<const SessionFrameSource*>(&Unwrapped(*built_)) != nullptr) {
      // The ladder's estimates: cached, or measured once on this machine (first use of the model).
      RunContext::ProgressRange range(ctx, 0.85, 1.0);
      RefineOptions refine;
      refine.data_dir = backend.data_dir;
      try {
        measured_ = CachedOrMeasuredQualityEstimates(*session, cache, ctx, refine);
      } catch (const Cancelled&) {
        throw;
      } catch (const Error& e) {
        AVATAR_LOG(kWarning) << "could not measure the quality ladder: " << e.what();
      }
    }
  });
}

void MainWindow::setFrameSource(std::shared_ptr<const FrameSource> source) {
  if (live_active_) stopLive();  // the live session drove the avatar being replaced
  source_ = std::move(source);
  preview_->setSource(source_);
  viewport_->setScene(nullptr);
  orbit_pending_ = false;
  if (source_) {
    expression_panel_->setSupported(source_->ExpressionControls());
    viewport_->setLabel(QString::fromStdString(source_->Label()));
    QString status = QString::fromStdString(source_->Label());
    for (const std::string& w : source_->Warnings()) status += tr("\nWarning: %1").arg(QString::fromStdString(w));
    source_panel_->setStatus(status);
    if (!portrait_.empty()) source_panel_->setPortrait(ToQImage(portrait_), source_->Overlay());
  }
  export_action_->setEnabled(source_ != nullptr);
  requestPreview();
  // After the first frame's request (the worker takes them in order): the meshes of the OpenGL
  // orbit, built once per source.
  preview_->buildScene(source_);
}

void MainWindow::requestPreview() {
  if (!source_ || live_active_) return;  // while live, the camera drives the viewport
  orbit_pending_ = false;
  PreviewRequest r;
  // The user's view offset; the worker composes it with the source's pose and the driver's
  // (ComposeFrame, as exports do).
  r.frame.view = pose_panel_->pose();
  r.frame.expression = expression_panel_->expression();
  r.frame.width = kPreviewSize;
  r.frame.height = kPreviewSize;
  if (driving_panel_->hasDriver()) {
    r.driver_frame = driving_panel_->currentFrame();
    r.driver_pose = driving_panel_->followPose();
  }
  last_request_ = preview_->request(r);
}

bool MainWindow::redrawOrbit() {
  if (!source_ || live_active_ || !viewport_->hasScene() || driving_panel_->hasDriver()) return false;
  const DetailFrameSource* detail = DetailFrameSource::Find(source_.get());
  if (detail == nullptr) return false;
  QElapsedTimer timer;
  timer.start();
  const FrameRequest r = ComposeFrame(source_->SourcePose(), pose_panel_->pose(), expression_panel_->expression(),
                                      nullptr, false, kPreviewSize, kPreviewSize);
  const DetailFrameSource::MeshView view = detail->ViewportView(r);
  // Depth range: the head sits about kCameraRadius / zoom from the camera.
  const std::array<float, 3> eye = {view.camera[3], view.camera[7], view.camera[11]};  // cam2world's centre
  viewport_->showScene(render::GlClipFromWorld(view.camera, 0.05, 50.0), eye, view.face);
  orbit_pending_ = true;
  ++mesh_orbit_frames_;
  frame_time_label_->setText(tr("Frame: meshes redrawn with OpenGL (camera move, %1 ms to pose them: no network); "
                                "the full frame follows when you let go")
                                 .arg(static_cast<double>(timer.nsecsElapsed()) / 1e6, 0, 'f', 1));
  return true;
}

void MainWindow::onFrame(const PreviewFrame& frame) {
  last_frame_ = frame.image;
  last_alpha_ = frame.alpha;
  if (frame.stages.isEmpty()) last_shown_ = frame.serial;
  last_driver_frame_ = frame.driver_frame;
  // During an orbit drag drawn by the meshes a frame of an earlier view would jump back: the
  // meshes stay until the drag's own full frame arrives.
  if (!orbit_pending_) {
    viewport_->setImage(frame.image);
    viewport_->setOverlay(frame.landmarks, frame.vertices, frame.triangles);
    // Which stages ran: a quick frame (the face at the new expression over the last network
    // frame) is followed by the full one.
    frame_time_label_->setText(frame.stages.isEmpty()
                                   ? tr("Frame: %1 ms (full frame)").arg(frame.milliseconds, 0, 'f', 1)
                                   : tr("Frame: %1 ms (%2; the full frame follows)")
                                         .arg(frame.milliseconds, 0, 'f', 1)
                                         .arg(frame.stages));
  }
  if (frame.driver_frame >= 0) driving_panel_->setDriverImage(frame.driver_image, frame.driver_face_found);
  if (!frame.stages.isEmpty()) {
    emit quickFrameShown(frame.serial);
    return;  // the request is answered by its full frame
  }
  emit frameShown(frame.serial);
}

void MainWindow::playTick() {
  if (!driving_panel_->hasDriver()) return;
  // Advance only once the previous frame is on screen, so playback stays sequential (the
  // smoothing needs it) and slows down instead of piling up requests.
  if (last_shown_ < last_request_) return;
  int next = driving_panel_->currentFrame() + 1;
  if (next >= driving_panel_->frameCount()) next = 0;
  driving_panel_->setCurrentFrame(next);
}

void MainWindow::stepDriver(int delta) {
  if (!driving_panel_->hasDriver()) return;
  driving_panel_->setPlaying(false);
  const int n = static_cast<int>(driving_panel_->frameCount());
  driving_panel_->setCurrentFrame(std::clamp(driving_panel_->currentFrame() + delta, 0, n - 1));
}

QString MainWindow::statusText() const { return status_label_->text(); }

QString MainWindow::frameTimeText() const { return frame_time_label_->text(); }

void MainWindow::showNeutralInUse() {
  // The panel shows the neutral frame actually used (the driver's choice when the requested
  // frame has no face); its signals are blocked, so this does not ask the driver again.
  if (neutral_in_use_ < 0 || !driving_panel_->hasDriver()) return;
  DrivingOptions o = driving_panel_->options();
  if (o.neutral_frame == neutral_in_use_) return;
  o.neutral_frame = neutral_in_use_;
  driving_panel_->setOptions(o);
}

void MainWindow::openDriver(const QString& path) {
  driving_panel_->setPlaying(false);
  // A neutral frame belongs to its clip: a new clip starts from frame 0 (or the first frame
  // with a face, which the driver picks and reports).
  DrivingOptions options = driving_panel_->options();
  options.neutral_frame = 0;
  driving_panel_->setOptions(options);
  driving_note_.clear();
  neutral_in_use_ = -1;
  loading_driver_ = true;
  preview_->loadDriver(path, options);
}

bool MainWindow::startExport(const ExportOptions& output, const AnimationPlan& plan_in) {
  if (!source_) {
    showError(tr("Cannot export"), tr("Open a portrait first (File > Open)."));
    return false;
  }
  if (jobs_->isBusy()) {
    showError(tr("Cannot export"), tr("Another job is running; wait for it or cancel it (Esc)."));
    return false;
  }
  driving_panel_->setPlaying(false);
  AnimationPlan plan = plan_in;
  plan.base_expression = expression_panel_->expression();
  plan.view.zoom = pose_panel_->pose().zoom;
  const std::shared_ptr<const FrameSource> source = source_;
  const QString driver_path = driving_panel_->driverPath();
  const DrivingOptions driving = driving_panel_->options();
  const BackendOptions backend = backendOptions();
  export_output_ = QString::fromStdString(output.output);
  export_frames_ = 0;
  return jobs_->start(kExportTitle, [this, source, driver_path, driving, backend, plan, output](RunContext& ctx) {
    std::unique_ptr<Driver> driver;
    if (!driver_path.isEmpty()) driver = OpenDriver(driver_path.toStdString(), DrivingAnalyzers(backend), driving, ctx);
    const ExportStats stats = ExportAnimation(*source, driver.get(), plan, output, ctx);
    export_frames_ = stats.frames;
  });
}

void MainWindow::showExportDialog() {
  if (!source_) return;
  ExportDialog dialog(driving_panel_->hasDriver(), source_panel_->config(), this);
  if (dialog.exec() != QDialog::Accepted) return;
  startExport(dialog.exportOptions(), dialog.plan());
}

void MainWindow::cancelJob() {
  if (live_active_) stopLive();
  if (!jobs_->isBusy()) return;
  stage_label_->setText(tr("cancelling..."));
  jobs_->cancel();
}

void MainWindow::onJobStarted(const QString& title) {
  progress_->setValue(0);
  progress_->setVisible(true);
  cancel_button_->setVisible(true);
  cancel_action_->setEnabled(true);
  stage_label_->setText(title);
  source_panel_->reconstructButton()->setEnabled(false);
  reconstruct_action_->setEnabled(false);
  export_action_->setEnabled(false);
}

void MainWindow::onJobProgress(const QString& stage, double fraction, const QString& message) {
  progress_->setValue(static_cast<int>(fraction * 1000.0));
  stage_label_->setText(message.isEmpty() ? stage : tr("%1: %2").arg(stage, message));
}

void MainWindow::onJobEnded() {
  progress_->setVisible(false);
  cancel_button_->setVisible(false);
  cancel_action_->setEnabled(false);
  stage_label_->clear();
  source_panel_->reconstructButton()->setEnabled(!portrait_.empty());
  reconstruct_action_->setEnabled(!portrait_.empty());
  export_action_->setEnabled(source_ != nullptr);
}

void MainWindow::saveExpressionPreset() {
  const QString path = QFileDialog::getSaveFileName(this, tr("Save Expression Preset"),
                                                    QSettings().value("expression/lastPreset").toString(),
                                                    tr("Expression presets (*.json)"));
  if (path.isEmpty()) return;
  try {
    expression_panel_->savePreset(path);
    QSettings().setValue("expression/lastPreset", path);
  } catch (const std::exception& e) {
    showError(tr("Could not save the expression preset"), QString::fromStdString(e.what()));
  }
}

void MainWindow::loadExpressionPreset() {
  const QString path = QFileDialog::getOpenFileName(this, tr("Load Expression Preset"),
                                                    QSettings().value("expression/lastPreset").toString(),
                                                    tr("Expression presets (*.json)"));
  if (path.isEmpty()) return;
  try {
    expression_panel_->loadPreset(path);
    QSettings().setValue("expression/lastPreset", path);
  } catch (const std::exception& e) {
    showError(tr("Could not load the expression preset"), QString::fromStdString(e.what()));
  }
}

void MainWindow::dragEnterEvent(QDragEnterEvent* event) {
  if (!LocalFileFromMime(event->mimeData()).isEmpty()) event->acceptProposedAction();
}

void MainWindow::dropEvent(QDropEvent* event) {
  const QString path = LocalFileFromMime(event->mimeData());
  if (path.isEmpty()) return;
  event->acceptProposedAction();
  if (IsDriverVideoFile(path)) {
    openDriver(path);
  } else {
    openPortrait(path);
  }
}

void MainWindow::showLiveDialog() {
  if (!source_) {
    showError(tr("Live"), tr("Open and reconstruct a portrait first: live driving moves its avatar."));
    return;
  }
  const std::vector<std::string> cameras = ListCameras();
  QStringList items;
  for (const auto& c : cameras) items << QString::fromStdString(c);
  const QString from_file = tr("A video file, played as a camera...");
  items << from_file;
  QString choice = from_file;
  if (dialogs_enabled_) {
    const QString label = cameras.empty()
                              ? tr("No camera was found on this machine (no /dev/video* device opens).\n"
                                   "Connect one and choose Live again, or play a video file as a camera:")
                              : tr("Camera to drive the avatar:");
    bool ok = false;
    choice = QInputDialog::getItem(this, tr("Live from Camera"), label, items, 0, false, &ok);
    if (!ok) return;
  } else if (!cameras.empty()) {
    choice = items.front();
  }
  if (choice == from_file) {
    if (!dialogs_enabled_) {
      showError(tr("Live"), tr("No camera was found on this machine (no /dev/video* device opens)."));
      return;
    }
    choice = QFileDialog::getOpenFileName(this, tr("Video to Play as a Camera"), QString(),
                                          tr("Videos (*.mp4 *.avi *.mov *.mkv *.webm);;All files (*)"));
    if (choice.isEmpty()) return;
  }
  startLive(choice);
}

bool MainWindow::startLive(const QString& camera) {
  if (!source_) {
    showError(tr("Live"), tr("Open and reconstruct a portrait first: live driving moves its avatar."));
    return false;
  }
  stopLive();
  driving_panel_->setPlaying(false);
  LiveOptions o;
  o.camera = camera.toStdString();
  o.width = o.height = 256;
  o.driving = driving_panel_->options();
  o.follow_pose = driving_panel_->followPose();
  try {
    // As `live` does (LiveFrameSource): the network takes a new expression on every 4th frame,
    // the photo's face follows every frame, no fusion net (the sliders' and exports' source
    // keeps every expression and the net).
    live_->start(LiveFrameSource(source_), DrivingAnalyzers(backendOptions()), o.camera, o);
  } catch (const std::exception& e) {
    showError(tr("Live"), QString::fromUtf8(e.what()));
    return false;
  }
  live_active_ = true;
  stop_live_action_->setEnabled(true);
  last_error_.clear();
  status_label_->setText(tr("Live: driven by %1 (Esc or Driving > Stop Live ends it).").arg(camera));
  return true;
}

void MainWindow::stopLive() {
  if (live_ == nullptr) return;
  const bool was_live = live_active_;
  live_active_ = false;
  live_->stop();
  if (was_live) requestPreview();  // the sliders' frame again
}

void MainWindow::onLiveFrame(const LiveFrame& frame) {
  if (!live_active_) return;  // queued before the session stopped
  last_frame_ = frame.image;
  last_alpha_ = QImage();
  viewport_->setImage(frame.image);
  viewport_->setOverlay({}, {}, {});
  frame_time_label_->setText(tr("Live: %1 fps, %2 ms from capture (render %3 ms)")
                                 .arg(frame.fps, 0, 'f', 1)
                                 .arg(frame.latency_ms, 0, 'f', 0)
                                 .arg(frame.render_ms, 0, 'f', 0));
  driving_panel_->setDriverImage(frame.camera, frame.face_found);
  emit liveFrameShown(frame.capture_index);
}

void MainWindow::closeEvent(QCloseEvent* event) {
  stopLive();
  QSettings settings;
  settings.setValue(kGeometryKey, saveGeometry());
  settings.setValue(kStateKey, saveState());
  QMainWindow::closeEvent(event);
}

QStringList MainWindow::recentFiles() const { return QSettings().value(kRecentKey).toStringList(); }

void MainWindow::addRecentFile(const QString& path) {
  QStringList files = recentFiles();
  files.removeAll(path);
  files.prepend(path);
  while (files.size() > kMaxRecentFiles) files.removeLast();
  QSettings().setValue(kRecentKey, files);
  rebuildRecentMenu();
}

void MainWindow::rebuildRecentMenu() {
  recent_menu_->clear();
  const QStringList files = recentFiles();
  for (const QString& f : files) {
    recent_menu_->addAction(QFileInfo(f).fileName(), this, [this, f] { openPortrait(f); })->setToolTip(f);
  }
  recent_menu_->setEnabled(!files.isEmpty());
}

void MainWindow::showOpenDialog() {
  const QString path = QFileDialog::getOpenFileName(this, tr("Open Portrait"), QString(),
                                                    tr("Images (*.jpg *.jpeg *.png *.bmp *.tif *.tiff *.webp)"));
  if (!path.isEmpty()) openPortrait(path);
}

void MainWindow::showOpenDriverDialog() {
  const QString path =
      QFileDialog::getOpenFileName(this, tr("Open Driving Video"), QSettings().value("driving/lastFolder").toString(),
                                   tr("Videos (*.mp4 *.mov *.avi *.mkv *.webm *.m4v)"));
  if (path.isEmpty()) return;
  QSettings().setValue("driving/lastFolder", QFileInfo(path).absolutePath());
  openDriver(path);
}

void MainWindow::showAbout() {
  QMessageBox::about(this, tr("About Avatar Studio"),
                     tr("<b>Avatar Studio %1</b><p>Turns one portrait photo into an animatable 3D head avatar "
                        "(Generalizable One-shot Neural Head Avatar, NeurIPS 2023).</p>"
                        "<p>The viewport renders the bundled neural avatar model (a small CPU model trained on "
                        "this project's packaged photos; see docs/MODEL.md), or the morphable-model preview when "
                        "chosen or when no model loads. Its label always says which.</p>")
                         .arg(QString::fromLatin1(kVersion)));
}

}  // namespace avatar::ui
