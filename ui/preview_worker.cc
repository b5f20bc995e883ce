// LibTorch headers first: Qt's `slots` keyword macro breaks them when it is defined earlier.
#include <c10/core/InferenceMode.h>

#include "ui/preview_worker.h"

#include <QElapsedTimer>
#include <QMetaObject>

#include <map>

#include "core/io/video_io.h"
#include "core/util/error.h"
#include "ui/image_convert.h"

namespace avatar::ui {

struct PreviewWorker::DriverState {
  QString path;
  std::unique_ptr<VideoReader> reader;
  std::unique_ptr<FrameAnalyzer> analyzer;
  DrivingOptions options;
  std::unique_ptr<DrivingTransfer> transfer;
  std::map<int64_t, FrameMeasurement> measured;  // Small per frame (a pose and ~64 floats).
  int64_t last_index = -2;
  cv::Mat frame;

  FrameMeasurement Measure(int64_t index, RunContext& ctx, cv::Mat* frame_out) {
    if (reader->NextIndex() != index) {
      reader->Seek(index);
      if (analyzer) analyzer->Reset();
    }
    cv::Mat f;
    if (!reader->Read(f)) throw InvalidInput("cannot read frame " + std::to_string(index) + " of the driving video");
    if (frame_out != nullptr) *frame_out = f;
    auto it = measured.find(index);
    if (it != measured.end()) return it->second;
    FrameMeasurement m;
    if (analyzer) m = analyzer->Measure(f, ctx);
    measured[index] = m;
    return m;
  }

  void ApplyOptions(const DrivingOptions& o, RunContext& ctx) {
    options = o;
    transfer = std::make_unique<DrivingTransfer>(o);
    if (analyzer && o.relative) {
      const int64_t n = std::clamp<int64_t>(o.neutral_frame, 0, std::max<int64_t>(0, reader->Info().frame_count - 1));
      transfer->SetNeutral(Measure(n, ctx, nullptr));
    }
    last_index = -2;
  }
};

PreviewWorker::PreviewWorker(QObject* parent) : QObject(parent) {
  qRegisterMetaType<avatar::ui::PreviewFrame>();
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
      auto state = std::make_unique<DriverState>();
      state->path = path;
      state->reader = std::make_unique<VideoReader>(path.toStdString());
      RunContext ctx;
      if (analyzers_) state->analyzer = analyzers_(ctx);
      state->ApplyOptions(options, ctx);
      const VideoInfo info = state->reader->Info();
      const bool measured = state->analyzer != nullptr;
      driver_ = std::move(state);
      emit driverLoaded(path, info.frame_count, info.fps, measured, info.has_audio);
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
      driver_->ApplyOptions(options, ctx);
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
      PreviewFrame frame = renderOne(next, source);
      frame.serial = serial;
      ++rendered_;
      emit frameReady(frame);
    } catch (const std::exception& e) {
      emit renderFailed(QString::fromStdString(e.what()));
    }
  }
}

PreviewFrame PreviewWorker::renderOne(const PreviewRequest& request, const std::shared_ptr<const FrameSource>& source) {
  QElapsedTimer clock;
  clock.start();
  RunContext ctx;
  FrameRequest frame_request = request.frame;
  PreviewFrame out;
  if (request.driver_frame >= 0 && driver_) {
    cv::Mat video_frame;
    FrameMeasurement m = driver_->Measure(request.driver_frame, ctx, &video_frame);
    // Smoothing only applies while playing forward; a jump restarts it.
    const bool sequential = request.driver_frame == driver_->last_index + 1;
    if (!sequential) driver_->transfer->ResetHistory();
    driver_->last_index = request.driver_frame;
    const DrivingSample sample = driver_->transfer->Apply(m, true);
    out.driver_frame = request.driver_frame;
    out.driver_face_found = driver_->analyzer == nullptr || m.face_found;
    out.driver_image = ToQImage(video_frame);
    if (driver_->analyzer) {
      frame_request.expression.coefficients = sample.expression.coefficients;
      frame_request.expression.coefficients_absolute = sample.expression.coefficients_absolute;
      if (request.driver_pose) {
        frame_request.view.yaw += sample.pose.yaw;
        frame_request.view.pitch += sample.pose.pitch;
        frame_request.view.roll += sample.pose.roll;
      }
    }
  }
  RenderedFrame rendered = source->Render(frame_request, ctx);
  out.image = ToQImage(rendered.bgr);
  if (!rendered.alpha.empty()) {
    out.alpha = QImage(rendered.alpha.data, rendered.alpha.cols, rendered.alpha.rows,
                       static_cast<qsizetype>(rendered.alpha.step), QImage::Format_Grayscale8)
                    .copy();
  }
  for (const auto& p : rendered.landmarks) out.landmarks.emplace_back(p.x, p.y);
  for (const auto& p : rendered.vertices) out.vertices.emplace_back(p.x, p.y);
  out.triangles = rendered.triangles;
  out.milliseconds = static_cast<double>(clock.nsecsElapsed()) / 1e6;
  return out;
}

}  // namespace avatar::ui
