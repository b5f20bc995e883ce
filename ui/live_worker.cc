#include "ui/live_worker.h"

#include <QMetaObject>

#include <iomanip>
#include <sstream>

#include "core/util/error.h"
#include "ui/image_convert.h"

namespace avatar::ui {

LiveWorker::LiveWorker(QObject* parent) : QObject(parent) { qRegisterMetaType<LiveFrame>("avatar::ui::LiveFrame"); }

LiveWorker::~LiveWorker() { stop(); }

void LiveWorker::start(std::shared_ptr<const FrameSource> source, FrameAnalyzerFactory analyzers,
                       const std::string& camera, const LiveOptions& options) {
  stop();
  AVATAR_CHECK_INPUT(source != nullptr) << "nothing to drive: open and reconstruct a portrait first";
  AVATAR_CHECK_INPUT(static_cast<bool>(analyzers)) << "this build cannot analyse camera frames (no face analysis)";
  options.Validate();
  auto grabber = std::make_shared<CameraGrabber>(camera);  // throws a clear error for a missing camera
  ctx_ = std::make_unique<RunContext>();
  finished_ = false;
  RunContext* ctx = ctx_.get();
  thread_ = std::thread([this, source, analyzers, grabber, options, ctx] {
    QString summary;
    bool failed = false;
    try {
      std::unique_ptr<FrameAnalyzer> analyzer = analyzers(*ctx);
      AVATAR_CHECK_INPUT(analyzer != nullptr) << "this build cannot analyse camera frames (no face analysis)";
      const auto start = LiveClock::now();
      int64_t delivered = 0;
      const LiveStats stats = RunLive(
          *source, *analyzer, *grabber, options,
          [&](const RenderedFrame& rendered, const LiveFrameInfo& info) {
            ++delivered;
            LiveFrame f;
            f.image = ToQImage(rendered.bgr);
            f.camera = ToQImage(info.camera_bgr);
            f.face_found = info.face_found;
            f.capture_index = info.capture_index;
            f.latency_ms = info.latency_ms;
            f.render_ms = info.render_ms;
            const double s = std::chrono::duration<double>(LiveClock::now() - start).count();
            f.fps = s > 0.0 ? static_cast<double>(delivered) / s : 0.0;
            if (!info.note.empty()) emit noteReady(QString::fromStdString(info.note));
            emit frameReady(f);
          },
          *ctx);
      std::ostringstream line;
      line << "Live ended (" << stats.ended << "): " << stats.delivered << " frames of " << stats.captured
           << " captured, " << std::fixed << std::setprecision(1) << stats.delivered_fps << " fps, latency "
           << std::setprecision(0) << stats.latency_median_ms << " ms median.";
      summary = QString::fromStdString(line.str());
    } catch (const Cancelled&) {
      summary = QStringLiteral("Live stopped.");
    } catch (const std::exception& e) {
      summary = QStringLiteral("Live driving failed: %1").arg(QString::fromUtf8(e.what()));
      failed = true;
    }
    finished_ = true;
    emit ended(summary, failed);
  });
}

void LiveWorker::stop() {
  if (!thread_.joinable()) return;
  if (ctx_) ctx_->RequestCancel();
  thread_.join();
  ctx_.reset();
}

}  // namespace avatar::ui
