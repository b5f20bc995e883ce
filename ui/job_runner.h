#pragma once
// Runs long core jobs (reconstruction, export) on a worker thread, one at a time, and
// reports back on the GUI thread. The GUI thread never blocks on the model: it starts a job
// and reacts to the queued signals. Cancel sets the job's RunContext flag; the core stops at
// its next check. Threads are never terminated.

#include <QObject>
#include <QString>
#include <QThread>

#include <functional>
#include <memory>

#include "core/util/run_context.h"

namespace avatar::ui {

class JobRunner : public QObject {
  Q_OBJECT

 public:
  // The job body runs on the worker thread; it must poll ctx (Report / ThrowIfCancelled).
  using Job = std::function<void(RunContext& ctx)>;

  explicit JobRunner(QObject* parent = nullptr);
  ~JobRunner() override;  // Cancels a running job and waits for the worker to finish.

  // Starts `job` named `title`. Returns false (and starts nothing) if a job is running.
  bool start(const QString& title, Job job);
  bool isBusy() const { return busy_; }
  // Requests cancellation of the running job (no effect when idle).
  void cancel();

 signals:
  void started(const QString& title);
  void progress(const QString& stage, double fraction, const QString& message);
  void finished(const QString& title);
  void failed(const QString& title, const QString& message);
  void cancelled(const QString& title);

 private:
  QThread thread_;
  QObject* worker_ = nullptr;  // Lives on thread_.
  std::shared_ptr<RunContext> ctx_;
  bool busy_ = false;
};

}  // namespace avatar::ui
