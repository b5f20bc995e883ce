// LibTorch headers first: Qt's `slots` keyword macro breaks them when it is defined earlier.
#include <c10/core/InferenceMode.h>
#include "core/pipeline/detail_source.h"
#include "core/pipeline/head_mesh.h"

#include "ui/preview_worker.h"

#include <QElapsedTimer>
#include <QMetaObject>

#include "core/util/error.h"
#include "core/util/logging.h"
#include "ui/image_convert.h"

namespace avatar::ui {

struct PreviewWorker::DriverState {
  QString path;
  std::unique_ptr<DrivingVideo> video;
};

PreviewWorker::PreviewWorker(QObject* parent) : QObject(parent) {
  qRegisterMetaType<avatar::ui::PreviewFrame>();
  qRegisterMetaType<avatar::ui::ScenePtr>();
  worker_ = new QObject;
  worker_->moveToThread(&thread_);
  connect(&thread_, &QThread::finished, worker_, &QObject::deleteLater);
  thread_.setObjectName(QStringLiteral("avatar-preview"));
  thread_.start();
}

PreviewWorker::~PreviewWorker() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    pending_.reset();
  }
  thread_.quit();
  thread_.wait();
  driver_.reset();
}

void PreviewWorker::setSource(std::shared_ptr<const FrameSource> source) {
  std::lock_guard<std::mutex> lock(mutex_);
  source_ = std::move(source);
}

void PreviewWorker::buildScene(std::shared_ptr<const FrameSource> source) {
  if (!source || DetailFrameSource::Find(source.get()) == nullptr) return;
  QMetaObject::invokeMethod(worker_, [this, source = std::move(source)] {
    c10::InferenceMode inference;
    try {
      RunContext ctx;
      ScenePtr scene = DetailFrameSource::Find(source.get())->ViewportMesh(ctx);
      emit sceneReady(reinterpret_cast<quintptr>(source.get()), std::move(scene));
    } catch (const std::exception& e) {
      AVATAR_LOG(kWarning) << "viewport: no meshes for the OpenGL orbit (" << e.what()
                           << "); orbiting renders every frame";
    }
  });
}

std::shared_ptr<const FrameSource> PreviewWorker::source() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return source_;
}

bool PreviewWorker::isIdle() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return !scheduled_ && !rendering_ && !pending_.has_value();
}

void PreviewWorker::setAnalyzerFactory(FrameAnalyzerFactory factory) {
  QMetaObject::invokeMethod(worker_, [this, factory = std::move(factory)] { analyzers_ = factory; });
}

void PreviewWorker::loadDriver(const QString& path, const DrivingOptions& options) {
  QMetaObject::invokeMethod(worker_, [this, path, options] {
    c10::InferenceMode inference;
    try {
      options.Validate();
      RunContext ctx;
      std::unique_ptr<FrameAnalyzer> analyzer = analyzers_ ? analyzers_(ctx) : nullptr;
      auto state = std::make_unique<DriverState>();
      state->path = path;
      state->video = std::make_unique<DrivingVideo>(path.toStdString(), std::move(analyzer), options, ctx);
      const DrivingVideo& v = *state->video;
      const qint64 frames = v.FrameCount();
      const double fps = v.Fps();
      const bool measured = v.Measured();
      const bool audio = v.HasAudio();
      const qint64 neutral = v.NeutralFrame();
      const QString note = QString::fromStdString(v.NeutralNote());
      driver_ = std::move(state);
      emit drivingNeutralChosen(neutral, note);
      emit driverLoaded(path, frames, fps, measured, audio);
    } catch (const std::exception& e) {
      emit driverFailed(path, QString::fromStdString(e.what()));
    }
  });
}

void PreviewWorker::setDrivingOptions(const DrivingOptions& options) {
  QMetaObject::invokeMethod(worker_, [this, options] {
    if (!driver_) return;
    c10::InferenceMode inference;
    try {
      RunContext ctx;
      driver_->video->SetOptions(options, ctx);
      emit drivingNeutralChosen(driver_->video->NeutralFrame(), QString::fromStdString(driver_->video->NeutralNote()));
    } catch (const std::exception& e) {
      emit renderFailed(QString::fromStdString(e.what()));
    }
  });
}

void PreviewWorker::unloadDriver() {
  QMetaObject::invokeMethod(worker_, [this] { driver_.reset(); });
}

quint64 PreviewWorker::request(const PreviewRequest& request) {
  ++requests_;
  std::lock_guard<std::mutex> lock(mutex_);
  pending_ = request;
  pending_serial_ = next_serial_++;
  if (!scheduled_) {
    scheduled_ = true;
    QMetaObject::invokeMethod(worker_, [this] { drain(); });
  }
  return pending_serial_;
}

void PreviewWorker::drain() {
  c10::InferenceMode inference;
  while (true) {
    PreviewRequest next;
    quint64 serial = 0;
    std::shared_ptr<const FrameSource> source;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (!pending_.has_value()) {
        scheduled_ = false;
        rendering_ = false;
        return;
      }
      next = *pending_;
      serial = pending_serial_;
      pending_.reset();
      source = source_;
      rendering_ = true;
    }
    if (!source) continue;
    try {
      if (std::optional<PreviewFrame> quick = renderQuick(next, source)) {
        quick->serial = serial;
        ++quick_;
        emit frameReady(*quick);
        std::lock_guard<std::mutex> lock(mutex_);
        if (pending_.has_value()) continue;  // a newer request: its frame, not this one's full frame
      }
      PreviewFrame frame = renderOne(next, source);
      frame.serial = serial;
      ++rendered_;
      emit frameReady(frame);
    } catch (const std::exception& e) {
      emit renderFailed(QString::fromStdString(e.what()));
    }
  }
}

namespace {

// A rendered frame as the viewport takes it (the time is filled in by the caller).
PreviewFrame ToPreview(const RenderedFrame& rendered) {
  PreviewFrame out;
  out.image = ToQImage(rendered.bgr);
  if (!rendered.alpha.empty()) {
    out.alpha = QImage(rendered.alpha.data, rendered.alpha.cols, rendered.alpha.rows,
                       static_cast<qsizetype>(rendered.alpha.step), QImage::Format_Grayscale8)
                    .copy();
  }
  for (const auto& p : rendered.landmarks) out.landmarks.emplace_back(p.x, p.y);
  for (const auto& p : rendered.vertices) out.vertices.emplace_back(p.x, p.y);
  out.triangles = rendered.triangles;
  out.stages = QString::fromStdString(rendered.stages);
  return out;
}

}  // namespace

std::optional<PreviewFrame> PreviewWorker::renderQuick(const PreviewRequest& request,
                                                       const std::shared_ptr<const FrameSource>& source) {
  if (request.driver_frame >= 0) return std::nullopt;  // driven frames change the view too
  QElapsedTimer clock;
  clock.start();
  RunContext ctx;
  const FrameRequest frame_request = ComposeFrame(source->SourcePose(), request.frame.view, request.frame.expression,
                                                  nullptr, false, request.frame.width, request.frame.height);
  std::optional<RenderedFrame> rendered = source->RenderQuick(frame_request, ctx);
  if (!rendered) return std::nullopt;
  PreviewFrame out = ToPreview(*rendered);
  out.milliseconds = static_cast<double>(clock.nsecsElapsed()) / 1e6;
  return out;
}

PreviewFrame PreviewWorker::renderOne(const PreviewRequest& request, const std::shared_ptr<const FrameSource>& source) {
  QElapsedTimer clock;
  clock.start();
  RunContext ctx;
  PreviewFrame out;
  DrivingSample sample;
  bool driven = false;
  if (request.driver_frame >= 0 && driver_) {
    cv::Mat video_frame;
    if (!driver_->video->At(request.driver_frame, sample, ctx, &video_frame)) {
      throw InvalidInput("cannot read frame " + std::to_string(request.driver_frame) + " of the driving video");
    }
    driven = driver_->video->Measured();
    out.driver_frame = request.driver_frame;
    out.driver_face_found = sample.face_found;
    out.driver_image = ToQImage(video_frame);
  }
  const FrameRequest frame_request =
      ComposeFrame(source->SourcePose(), request.frame.view, request.frame.expression, driven ? &sample : nullptr,
                   request.driver_pose, request.frame.width, request.frame.height);
  const RenderedFrame rendered = source->Render(frame_request, ctx);
  const int64_t driver_frame = out.driver_frame;
  const bool face_found = out.driver_face_found;
  QImage driver_image = out.driver_image;
  out = ToPreview(rendered);
  out.driver_frame = driver_frame;
  out.driver_face_found = face_found;
  out.driver_image = driver_image;
  out.milliseconds = static_cast<double>(clock.nsecsElapsed()) / 1e6;
  return out;
}

}  // namespace avatar::ui
