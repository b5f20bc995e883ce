// LibTorch headers first: Qt's `slots` keyword macro breaks them when it is defined earlier.
#include <c10/core/InferenceMode.h>

#include "ui/job_runner.h"

#include <QMetaObject>

#include "core/util/error.h"

namespace avatar::ui {

JobRunner::JobRunner(QObject* parent) : QObject(parent) {
  worker_ = new QObject;
  worker_->moveToThread(&thread_);
  connect(&thread_, &QThread::finished, worker_, &QObject::deleteLater);
  thread_.setObjectName(QStringLiteral("avatar-job"));
  thread_.start();
}

JobRunner::~JobRunner() {
  if (ctx_) ctx_->RequestCancel();
  thread_.quit();
  thread_.wait();
}

bool JobRunner::start(const QString& title, Job job) {
  if (busy_) return false;
  busy_ = true;
  // The sink runs on the worker thread; queued signals carry progress to the GUI thread.
  auto ctx = std::make_shared<RunContext>([this](const Progress& p) {
    QMetaObject::invokeMethod(
        this,
        [this, p] { emit progress(QString::fromStdString(p.stage), p.fraction, QString::fromStdString(p.message)); },
        Qt::QueuedConnection);
  });
  ctx_ = ctx;
  emit started(title);
  QMetaObject::invokeMethod(worker_, [this, ctx, title, job = std::move(job)] {
    // Grad mode is per thread: inference jobs on this thread never record autograd history.
    c10::InferenceMode inference;
    QString error;
    bool was_cancelled = false;
    try {
      job(*ctx);
    } catch (const Cancelled&) {
      was_cancelled = true;
    } catch (const std::exception& e) {
      error = QString::fromStdString(e.what());
      if (error.isEmpty()) error = QStringLiteral("unknown error");
    }
    QMetaObject::invokeMethod(
        this,
        [this, ctx, title, error, was_cancelled] {
          if (ctx_ == ctx) ctx_.reset();
          busy_ = false;
          if (was_cancelled) {
            emit cancelled(title);
          } else if (!error.isEmpty()) {
            emit failed(title, error);
          } else {
            emit finished(title);
          }
        },
        Qt::QueuedConnection);
  });
  return true;
}

void JobRunner::cancel() {
  if (ctx_) ctx_->RequestCancel();
}

}  // namespace avatar::ui
