// The worker keeps the GUI thread free, reports progress in order, and cancels promptly.
#include <QElapsedTimer>
#include <QSignalSpy>
#include <QTimer>
#include <QtTest/QtTest>

#include <atomic>
#include <chrono>
#include <thread>

#include "core/util/error.h"
#include "ui/job_runner.h"

namespace avatar::ui {

class JobRunnerTest : public QObject {
  Q_OBJECT

 private slots:
  void eventLoopKeepsTurningDuringAJob() {
    JobRunner runner;
    QSignalSpy finished(&runner, &JobRunner::finished);
    QSignalSpy progress(&runner, &JobRunner::progress);
    // A 600 ms job in 20 steps, standing in for reconstruction.
    QVERIFY(runner.start(QStringLiteral("busy"), [](RunContext& ctx) {
      for (int i = 1; i <= 20; ++i) {
        std::this_thread::sleep_for(std::chrono::milliseconds(30));
        ctx.Report("step", i / 20.0);
      }
    }));
    QVERIFY(!runner.start(QStringLiteral("second"), [](RunContext&) {}));  // One job at a time.
    int ticks = 0;
    QTimer timer;
    connect(&timer, &QTimer::timeout, [&] { ++ticks; });
    timer.start(10);
    QVERIFY(finished.wait(5000));
    timer.stop();
    // The GUI thread handled timer events all along (600 ms / 10 ms = 60 possible ticks).
    QVERIFY2(ticks >= 20, qPrintable(QStringLiteral("only %1 timer ticks during the job").arg(ticks)));
    QCOMPARE(progress.count(), 20);
    QCOMPARE(progress.last().at(1).toDouble(), 1.0);
    QVERIFY(!runner.isBusy());
  }

  void cancelTakesEffectWithin250ms() {
    JobRunner runner;
    QSignalSpy cancelled(&runner, &JobRunner::cancelled);
    QSignalSpy finished(&runner, &JobRunner::finished);
    QVERIFY(runner.start(QStringLiteral("long"), [](RunContext& ctx) {
      for (int i = 0; i < 100000; ++i) {
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
        ctx.ThrowIfCancelled();
      }
    }));
    QTest::qWait(100);
    QElapsedTimer clock;
    clock.start();
    runner.cancel();
    QVERIFY(cancelled.wait(2000));
    const qint64 ms = clock.elapsed();
    qInfo("cancel took %lld ms", static_cast<long long>(ms));
    QVERIFY2(ms < 250, qPrintable(QStringLiteral("cancel took %1 ms").arg(ms)));
    QCOMPARE(finished.count(), 0);
  }

  void failuresArriveAsMessages() {
    JobRunner runner;
    QSignalSpy failed(&runner, &JobRunner::failed);
    QVERIFY(runner.start(QStringLiteral("bad"), [](RunContext&) { throw InvalidInput("no face found in 'x.jpg'"); }));
    QVERIFY(failed.wait(2000));
    QCOMPARE(failed.first().at(1).toString(), QStringLiteral("no face found in 'x.jpg'"));
    // The runner is free again.
    QSignalSpy finished(&runner, &JobRunner::finished);
    QVERIFY(runner.start(QStringLiteral("ok"), [](RunContext&) {}));
    QVERIFY(finished.wait(2000));
  }

  void destroyingTheRunnerCancelsTheJob() {
    std::atomic<bool> stopped{false};
    {
      JobRunner runner;
      runner.start(QStringLiteral("endless"), [&](RunContext& ctx) {
        while (true) {
          std::this_thread::sleep_for(std::chrono::milliseconds(2));
          if (ctx.IsCancelled()) {
            stopped = true;
            return;
          }
        }
      });
      QTest::qWait(20);
    }
    QVERIFY(stopped.load());
  }
};

}  // namespace avatar::ui

QTEST_MAIN(avatar::ui::JobRunnerTest)
#include "job_runner_test.moc"
