// The worker keeps the GUI thread free, reports progress in order, and cancels promptly.
#include <QElapsedTimer>
#include <QSignalSpy>
#include <QTimer>
#include <QtTest/QtTest>

#include "ui_test_main.h"

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <thread>

#include "core/util/error.h"
#include "ui/job_runner.h"

namespace avatar::ui {

class JobRunnerTest : public QObject {
  Q_OBJECT

 private slots:
  // The job cannot finish before the GUI thread has handled a timer tick while it runs: at
  // step 10 it waits for one (a GUI thread blocked by the job would never deliver it).
  void eventLoopKeepsTurningDuringAJob() {
    // Declared before the runner, which outlives them by waiting for its job on destruction.
    std::mutex mutex;
    std::condition_variable ticked_cv;
    bool ticked = false;
    std::atomic<bool> waited_in_vain{false};
    JobRunner runner;
    QSignalSpy finished(&runner, &JobRunner::finished);
    QSignalSpy progress(&runner, &JobRunner::progress);
    QVERIFY(runner.start(QStringLiteral("busy"), [&](RunContext& ctx) {
      for (int i = 1; i <= 20; ++i) {
        if (i == 10) {
          std::unique_lock<std::mutex> lock(mutex);
          if (!ticked_cv.wait_for(lock, std::chrono::seconds(10), [&] { return ticked; })) waited_in_vain = true;
        }
        ctx.Report("step", i / 20.0);
      }
    }));
    QVERIFY(!runner.start(QStringLiteral("second"), [](RunContext&) {}));  // One job at a time.
    // GUI-thread events handled while the job is still running: timer ticks and progress
    // signals delivered while the runner reports busy.
    int ticks_while_busy = 0;
    int progress_while_busy = 0;
    QTimer timer;
    connect(&timer, &QTimer::timeout, [&] {
      if (!runner.isBusy()) return;
      ++ticks_while_busy;
      std::lock_guard<std::mutex> lock(mutex);
      ticked = true;
      ticked_cv.notify_all();
    });
    connect(&runner, &JobRunner::progress, [&] { progress_while_busy += runner.isBusy() ? 1 : 0; });
    timer.start(10);
    QVERIFY(finished.wait(20000));
    timer.stop();
    qInfo("during the job the GUI thread handled %d timer ticks and %d progress signals", ticks_while_busy,
          progress_while_busy);
    QVERIFY2(!waited_in_vain.load(), "the GUI event loop did not turn while the job ran");
    QVERIFY(ticks_while_busy > 0);
    QCOMPARE(progress_while_busy, 20);
    QCOMPARE(progress.count(), 20);
    QCOMPARE(progress.last().at(1).toDouble(), 1.0);
    QVERIFY(!runner.isBusy());
  }

  // The job parks after its 10th step until the test has requested the cancel; its next check
  // must throw, so it never counts an 11th step and never reports success.
  void cancelStopsTheJobAtItsNextCheck() {
    std::mutex mutex;
    std::condition_variable changed;
    bool parked = false, cancel_requested = false;
    std::atomic<int> steps{0};
    std::atomic<bool> waited_in_vain{false};
    JobRunner runner;
    QSignalSpy cancelled(&runner, &JobRunner::cancelled);
    QSignalSpy finished(&runner, &JobRunner::finished);
    QVERIFY(runner.start(QStringLiteral("long"), [&](RunContext& ctx) {
      for (int i = 0; i < 100000; ++i) {
        ctx.ThrowIfCancelled();
        if (++steps == 10) {
          std::unique_lock<std::mutex> lock(mutex);
          parked = true;
          changed.notify_all();
          if (!changed.wait_for(lock, std::chrono::seconds(10), [&] { return cancel_requested; })) waited_in_vain = true;
        }
      }
    }));
    {
      std::unique_lock<std::mutex> lock(mutex);
      QVERIFY2(changed.wait_for(lock, std::chrono::seconds(10), [&] { return parked; }), "the job never started");
    }
    QElapsedTimer clock;
    clock.start();
    runner.cancel();
    {
      std::lock_guard<std::mutex> lock(mutex);
      cancel_requested = true;
      changed.notify_all();
    }
    QVERIFY(cancelled.wait(20000));
    // Latency is reported, not asserted (timing belongs in benchmarks).
    qInfo("cancel reached the GUI after %lld ms", static_cast<long long>(clock.elapsed()));
    QVERIFY(!waited_in_vain.load());
    QCOMPARE(steps.load(), 10);
    QCOMPARE(finished.count(), 0);
    QVERIFY(!runner.isBusy());
  }

  void failuresArriveAsMessages() {
    JobRunner runner;
    QSignalSpy failed(&runner, &JobRunner::failed);
    QVERIFY(runner.start(QStringLiteral("bad"), [](RunContext&) { throw InvalidInput("no face found in 'x.jpg'"); }));
    QVERIFY(failed.wait(20000));
    QCOMPARE(failed.first().at(1).toString(), QStringLiteral("no face found in 'x.jpg'"));
    // The runner is free again.
    QSignalSpy finished(&runner, &JobRunner::finished);
    QVERIFY(runner.start(QStringLiteral("ok"), [](RunContext&) {}));
    QVERIFY(finished.wait(20000));
  }

  void destroyingTheRunnerCancelsTheJob() {
    std::atomic<bool> stopped{false};
    std::atomic<bool> running{false};
    {
      JobRunner runner;
      QVERIFY(runner.start(QStringLiteral("endless"), [&](RunContext& ctx) {
        running = true;
        while (true) {
          std::this_thread::sleep_for(std::chrono::milliseconds(2));
          if (ctx.IsCancelled()) {
            stopped = true;
            return;
          }
        }
      }));
      // Destroy it only once the job is known to run (not merely queued).
      QTRY_VERIFY_WITH_TIMEOUT(running.load(), 20000);
    }
    QVERIFY(stopped.load());
  }
};

}  // namespace avatar::ui

AVATAR_UI_TEST(job_runner, avatar::ui::JobRunnerTest)
#include "job_runner_test.moc"
