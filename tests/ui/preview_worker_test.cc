// The preview worker renders off the GUI thread and coalesces requests: a burst of slider
// moves renders a handful of frames, and the last frame shown is the last state requested.
#include <QSignalSpy>
#include <QtTest/QtTest>

#include <atomic>
#include <chrono>
#include <thread>

#include "core/pipeline/frame_source.h"
#include "ui/preview_worker.h"

namespace avatar::ui {
namespace {

// A deliberately slow source whose frame encodes the requested yaw in its grey level, so
// the test can tell which request a frame answers.
class SlowSource : public FrameSource {
 public:
  std::string Label() const override { return "test pattern"; }
  bool SupportsPose() const override { return true; }
  std::vector<std::string> ExpressionControls() const override { return {"smile"}; }
  RenderedFrame Render(const FrameRequest& r, RunContext& ctx) const override {
    ++calls;
    std::this_thread::sleep_for(std::chrono::milliseconds(40));
    ctx.ThrowIfCancelled();
    RenderedFrame f;
    f.bgr = cv::Mat(r.height, r.width, CV_8UC3, cv::Scalar::all(static_cast<int>(r.view.yaw) + 100));
    f.alpha = cv::Mat(r.height, r.width, CV_8UC1, cv::Scalar(255));
    return f;
  }
  mutable std::atomic<int> calls{0};
};

}  // namespace

class PreviewWorkerTest : public QObject {
  Q_OBJECT

 private slots:
  void burstsAreCoalescedAndTheLatestStateWins() {
    PreviewWorker worker;
    auto source = std::make_shared<SlowSource>();
    worker.setSource(source);
    QSignalSpy frames(&worker, &PreviewWorker::frameReady);
    quint64 last_serial = 0;
    for (int yaw = -50; yaw <= 50; ++yaw) {  // 101 requests, far faster than 40 ms each.
      PreviewRequest r;
      r.frame.view.yaw = yaw;
      r.frame.width = r.frame.height = 32;
      last_serial = worker.request(r);
    }
    QTRY_VERIFY_WITH_TIMEOUT(worker.isIdle(), 20000);
    QTest::qWait(50);
    qInfo("101 requests -> %d renders", source->calls.load());
    QVERIFY(!frames.isEmpty());
    QVERIFY2(source->calls.load() <= 3, "requests were not coalesced");
    QCOMPARE(worker.requestsReceived(), quint64{101});
    const auto last = frames.last().at(0).value<PreviewFrame>();
    QCOMPARE(last.serial, last_serial);
    QCOMPARE(qGray(last.image.pixel(0, 0)), 150);  // yaw 50 -> grey 150.
    QCOMPARE(last.alpha.pixelColor(0, 0).value(), 255);
  }

  void theGuiThreadKeepsTurningWhileRendering() {
    PreviewWorker worker;
    auto source = std::make_shared<SlowSource>();
    worker.setSource(source);
    int ticks = 0;
    QTimer timer;
    connect(&timer, &QTimer::timeout, [&] { ++ticks; });
    timer.start(5);
    for (int i = 0; i < 5; ++i) {
      PreviewRequest r;
      r.frame.width = r.frame.height = 16;
      worker.request(r);
      QTRY_VERIFY_WITH_TIMEOUT(worker.isIdle(), 20000);
    }
    timer.stop();
    qInfo("GUI timer ticked %d times during 5 renders", ticks);
    QVERIFY(ticks > 5);
  }

  void renderErrorsArriveAsMessages() {
    PreviewWorker worker;
    worker.setSource(std::make_shared<PortraitFrameSource>(cv::Mat(10, 10, CV_8UC3, cv::Scalar::all(9))));
    QSignalSpy failed(&worker, &PreviewWorker::renderFailed);
    PreviewRequest r;
    r.frame.width = 5;  // Below the minimum size.
    worker.request(r);
    QVERIFY(failed.wait(5000));
    QVERIFY(failed.first().at(0).toString().contains(QStringLiteral("16..4096")));
  }

  void badDriverIsReportedNotThrown() {
    PreviewWorker worker;
    QSignalSpy failed(&worker, &PreviewWorker::driverFailed);
    worker.loadDriver(QStringLiteral("/no/such/clip.mp4"), DrivingOptions{});
    QVERIFY(failed.wait(5000));
    QVERIFY(failed.first().at(1).toString().contains(QStringLiteral("clip.mp4")));
  }
};

}  // namespace avatar::ui

QTEST_MAIN(avatar::ui::PreviewWorkerTest)
#include "preview_worker_test.moc"
