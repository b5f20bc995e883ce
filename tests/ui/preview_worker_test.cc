// The preview worker renders off the GUI thread and coalesces requests: a burst of slider
// moves renders a handful of frames, and the last frame shown is the last state requested.
// Its driving video is the export's driver: given the same clip (missed faces included) the
// preview and an export ask the source for the same camera and expression on every frame.
// LibTorch (via the morphable model, in common/synthetic_studio.h) first: Qt's `slots` macro breaks its headers.
#include "common/synthetic_studio.h"

#include <QCheckBox>
#include <QDeadlineTimer>
#include <QSettings>
#include <QSignalSpy>
#include <QStandardPaths>
#include <QTemporaryDir>
#include <QtTest/QtTest>

#include "ui_test_main.h"

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <filesystem>
#include <mutex>
#include <thread>

#include "core/io/data_paths.h"
#include "core/io/video_io.h"
#include "core/pipeline/animate.h"
#include "core/pipeline/frame_source.h"
#include "core/pipeline/studio_backend.h"
#include "ui/main_window.h"
#include "ui/panels.h"
#include "ui/preview_worker.h"
#include "ui/studio.h"
#include "ui/viewport.h"

namespace avatar::ui {
namespace {

// Records a signal that the preview worker emits on its own thread. QSignalSpy (Qt 6.4)
// connects directly, so it would append on the worker thread while the test reads it on the GUI
// thread (a data race), and its wait() counts only signals emitted after the call: a worker
// quicker than the test (an option error, under ThreadSanitizer) made `failed.wait()` time out.
// This spy takes the signal through the GUI thread's event queue and is read on that thread only.
class WorkerSpy : public QObject {
 public:
  template <typename Sender, typename... Args>
  WorkerSpy(const Sender* sender, void (Sender::*signal)(Args...)) {
    connect(
        sender, signal, this,
        [this](Args... args) {
          calls_.append(QVariantList{QVariant::fromValue(std::decay_t<Args>(args))...});
        },
        Qt::QueuedConnection);
  }
  // Turns the event loop until `n` signals in all have arrived; false after `timeout_ms`.
  bool waitForCount(qsizetype n, int timeout_ms) {
    QDeadlineTimer deadline(timeout_ms);
    while (calls_.size() < n && !deadline.hasExpired()) QTest::qWait(5);
    return calls_.size() >= n;
  }
  qsizetype count() const { return calls_.size(); }
  bool isEmpty() const { return calls_.isEmpty(); }
  const QVariantList& first() const { return calls_.first(); }
  const QList<QVariantList>& calls() const { return calls_; }
  const QVariantList& last() const { return calls_.last(); }

 private:
  QList<QVariantList> calls_;
};

// Holds renders until the test lets them through, so a test knows a frame is rendering (or not)
// from events instead of hoping a sleep was long enough.
class Gate {
 public:
  // Worker thread: counts the arrival, then waits for a pass; false when none came in 10 s.
  bool Pass() {
    std::unique_lock<std::mutex> lock(mutex_);
    ++arrived_;
    changed_.notify_all();
    const bool passed = changed_.wait_for(lock, std::chrono::seconds(10), [&] { return passes_ > 0; });
    if (passed) --passes_;
    return passed;
  }
  void Give(int passes) {
    std::lock_guard<std::mutex> lock(mutex_);
    passes_ += passes;
    changed_.notify_all();
  }
  int Arrived() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return arrived_;
  }
  bool WaitArrived(int n) {
    std::unique_lock<std::mutex> lock(mutex_);
    return changed_.wait_for(lock, std::chrono::seconds(10), [&] { return arrived_ >= n; });
  }

 private:
  mutable std::mutex mutex_;
  std::condition_variable changed_;
  int arrived_ = 0;
  int passes_ = 0;
};

// A source whose renders wait at a gate and whose frame encodes the requested yaw in its grey
// level, so the test can tell which request a frame answers.
class GatedSource : public FrameSource {
 public:
  std::string Label() const override { return "test pattern"; }
  bool SupportsPose() const override { return true; }
  std::vector<std::string> ExpressionControls() const override { return {"smile"}; }
  RenderedFrame Render(const FrameRequest& r, RunContext& ctx) const override {
    ++calls;
    if (std::this_thread::get_id() == gui_thread) ++calls_on_gui_thread;
    if (!gate.Pass()) ++gate_timeouts;
    ctx.ThrowIfCancelled();
    RenderedFrame f;
    f.bgr = cv::Mat(r.height, r.width, CV_8UC3, cv::Scalar::all(static_cast<int>(r.view.yaw) + 100));
    f.alpha = cv::Mat(r.height, r.width, CV_8UC1, cv::Scalar(255));
    return f;
  }
  const std::thread::id gui_thread = std::this_thread::get_id();  // made on the GUI thread
  mutable Gate gate;
  mutable std::atomic<int> calls{0};
  mutable std::atomic<int> calls_on_gui_thread{0};
  mutable std::atomic<int> gate_timeouts{0};
};

// Records every request it renders (a small black frame); has a pose of its own so the
// composition with the source pose is exercised.
class RecordingSource : public FrameSource {
 public:
  std::string Label() const override { return "recorder"; }
  bool SupportsPose() const override { return true; }
  std::vector<std::string> ExpressionControls() const override { return {}; }
  int CoefficientCount() const override { return 12; }
  ViewPose SourcePose() const override { return {6.0, -3.0, 2.0, 1.0}; }
  RenderedFrame Render(const FrameRequest& r, RunContext&) const override {
    {
      std::lock_guard<std::mutex> lock(mutex);
      requests.push_back(r);
    }
    RenderedFrame f;
    f.bgr = cv::Mat(r.height, r.width, CV_8UC3, cv::Scalar::all(0));
    f.alpha = cv::Mat(r.height, r.width, CV_8UC1, cv::Scalar(255));
    return f;
  }
  mutable std::mutex mutex;
  mutable std::vector<FrameRequest> requests;
};

// `frames` frames of the bundled face clip at 10 fps, 400x300, with the frames listed in
// `black` (an ffmpeg expression over n) painted black: no face there.
QString MakeClip(const QTemporaryDir& dir, const QString& name, int frames, const std::string& black) {
  const std::string source =
      DataPaths::Resolve().Require("samples/cap13_edit2.mp4", "a sample driving clip (run scripts/setup)").string();
  const std::string out = dir.filePath(name).toStdString();
  const int rc = RunProgram("ffmpeg", {"-nostdin", "-y", "-v", "error", "-i", source, "-an", "-vf",
                                       "fps=10,drawbox=enable='" + black + "':x=0:y=0:w=iw:h=ih:color=black:t=fill",
                                       "-frames:v", std::to_string(frames), "-c:v", "libx264", "-pix_fmt", "yuv420p",
                                       out});
  return rc == 0 ? QString::fromStdString(out) : QString();
}

}  // namespace

class PreviewWorkerTest : public QObject {
  Q_OBJECT

 private slots:
  // What a change recomputes (issue 34's scheduler): an expression change at an unchanged view
  // shows the source's quick frame first and then the full frame of the same serial; a camera
  // change renders the full frame only; a driven request never takes the quick path.
  void anExpressionChangeShowsItsQuickFrameFirst() {
    class QuickSource : public FrameSource {
     public:
      std::string Label() const override { return "quick"; }
      bool SupportsPose() const override { return true; }
      std::vector<std::string> ExpressionControls() const override { return {"jawOpen"}; }
      RenderedFrame Render(const FrameRequest& request, RunContext&) const override {
        ++full;
        std::lock_guard<std::mutex> lock(mutex);
        kept = request.view;
        has_kept = true;
        RenderedFrame f;
        f.bgr = cv::Mat(request.height, request.width, CV_8UC3, cv::Scalar::all(200));
        return f;
      }
      std::optional<RenderedFrame> RenderQuick(const FrameRequest& request, RunContext&) const override {
        std::lock_guard<std::mutex> lock(mutex);
        if (!has_kept || kept != request.view) return std::nullopt;
        ++quick;
        RenderedFrame f;
        f.bgr = cv::Mat(request.height, request.width, CV_8UC3, cv::Scalar::all(100));
        f.stages = "face update";
        return f;
      }
      mutable std::atomic<int> full{0}, quick{0};

     private:
      mutable std::mutex mutex;
      mutable ViewPose kept;
      mutable bool has_kept = false;
    };
    PreviewWorker worker;
    auto source = std::make_shared<QuickSource>();
    worker.setSource(source);
    WorkerSpy frames(&worker, &PreviewWorker::frameReady);
    PreviewRequest r;
    r.frame.width = r.frame.height = 32;
    worker.request(r);
    QVERIFY(frames.waitForCount(1, 20000));
    QCOMPARE(source->full.load(), 1);
    QCOMPARE(source->quick.load(), 0);  // nothing kept before the first frame
    // An expression change: the quick frame, then the full frame, one serial.
    r.frame.expression.controls["jawOpen"] = 0.7f;
    const quint64 serial = worker.request(r);
    QVERIFY(frames.waitForCount(3, 20000));
    const auto quick = frames.calls().at(1).at(0).value<PreviewFrame>();
    const auto full = frames.calls().at(2).at(0).value<PreviewFrame>();
    QCOMPARE(quick.serial, serial);
    QCOMPARE(full.serial, serial);
    QCOMPARE(quick.stages, QStringLiteral("face update"));
    QVERIFY(full.stages.isEmpty());
    QCOMPARE(qGray(quick.image.pixel(0, 0)), 100);
    QCOMPARE(qGray(full.image.pixel(0, 0)), 200);
    QCOMPARE(source->quick.load(), 1);
    QCOMPARE(source->full.load(), 2);
    QCOMPARE(worker.quickFrames(), quint64{1});
    // A camera change: the full frame only.
    r.frame.view.yaw = 20.0;
    worker.request(r);
    QVERIFY(frames.waitForCount(4, 20000));
    QTRY_VERIFY_WITH_TIMEOUT(worker.isIdle(), 20000);
    QCOMPARE(frames.count(), 4);
    QCOMPARE(source->quick.load(), 1);
    QCOMPARE(source->full.load(), 3);
  }

  // While the first frame renders (held at the gate), 100 more requests arrive: they collapse
  // into one, so exactly two renders happen, the first request's and the last one's.
  void burstsAreCoalescedAndTheLatestStateWins() {
    PreviewWorker worker;
    auto source = std::make_shared<GatedSource>();
    worker.setSource(source);
    WorkerSpy frames(&worker, &PreviewWorker::frameReady);
    PreviewRequest r;
    r.frame.width = r.frame.height = 32;
    r.frame.view.yaw = -50;
    const quint64 first_serial = worker.request(r);
    QVERIFY2(source->gate.WaitArrived(1), "the first request never started rendering");
    quint64 last_serial = 0;
    for (int yaw = -49; yaw <= 50; ++yaw) {
      r.frame.view.yaw = yaw;
      last_serial = worker.request(r);
    }
    source->gate.Give(100);
    QTRY_VERIFY_WITH_TIMEOUT(
        !frames.isEmpty() && frames.last().at(0).value<PreviewFrame>().serial == last_serial, 20000);
    QTRY_VERIFY_WITH_TIMEOUT(worker.isIdle(), 20000);
    qInfo("101 requests -> %d renders", source->calls.load());
    QCOMPARE(source->calls.load(), 2);
    QCOMPARE(frames.count(), 2);
    QCOMPARE(source->gate_timeouts.load(), 0);
    QCOMPARE(worker.requestsReceived(), quint64{101});
    QCOMPARE(worker.framesRendered(), quint64{2});
    const auto first = frames.first().at(0).value<PreviewFrame>();
    QCOMPARE(first.serial, first_serial);
    QCOMPARE(qGray(first.image.pixel(0, 0)), 50);  // yaw -50 -> grey 50.
    const auto last = frames.last().at(0).value<PreviewFrame>();
    QCOMPARE(qGray(last.image.pixel(0, 0)), 150);  // yaw 50 -> grey 150.
    QCOMPARE(last.alpha.pixelColor(0, 0).value(), 255);
  }

  // Each render waits until the GUI thread's event loop lets it through: a worker that rendered
  // on the GUI thread, or blocked it until the frame was done, would never get its pass.
  void theGuiThreadKeepsTurningWhileRendering() {
    PreviewWorker worker;
    auto source = std::make_shared<GatedSource>();
    worker.setSource(source);
    WorkerSpy frames(&worker, &PreviewWorker::frameReady);
    int passes_from_the_event_loop = 0;
    for (int i = 1; i <= 3; ++i) {
      PreviewRequest r;
      r.frame.width = r.frame.height = 16;
      const quint64 serial = worker.request(r);
      // The event loop turns while the frame is held at the gate...
      QTRY_VERIFY_WITH_TIMEOUT(source->gate.Arrived() == i, 20000);
      QCOMPARE(frames.count(), i - 1);
      // ...and a timer event on the GUI thread is what releases it.
      QTimer::singleShot(0, &worker, [&] {
        ++passes_from_the_event_loop;
        source->gate.Give(1);
      });
      QTRY_VERIFY_WITH_TIMEOUT(frames.count() == i, 20000);
      QCOMPARE(frames.last().at(0).value<PreviewFrame>().serial, serial);
    }
    QCOMPARE(passes_from_the_event_loop, 3);
    QCOMPARE(source->calls_on_gui_thread.load(), 0);
    QCOMPARE(source->gate_timeouts.load(), 0);
  }

  void renderErrorsArriveAsMessages() {
    PreviewWorker worker;
    worker.setSource(std::make_shared<PortraitFrameSource>(cv::Mat(10, 10, CV_8UC3, cv::Scalar::all(9))));
    WorkerSpy failed(&worker, &PreviewWorker::renderFailed);
    PreviewRequest r;
    r.frame.width = 5;  // Below the minimum size.
    worker.request(r);
    QVERIFY(failed.waitForCount(1, 5000));
    QVERIFY(failed.first().at(0).toString().contains(QStringLiteral("16..4096")));
  }

  void initTestCase() {
    const QString error = testing::UseSyntheticModelAndTestSettings(model_dir_);
    QVERIFY2(error.isEmpty(), qPrintable(error));
  }

  // Acceptance (issue 15): the preview and the export read the driver through one path.
  void previewAndExportGiveTheSameFramesMissedFacesIncluded() {
    QTemporaryDir dir;
    QVERIFY(dir.isValid());
    const int kFrames = 12;
    const QString clip = MakeClip(dir, QStringLiteral("gaps.mp4"), kFrames, "between(n,3,5)+eq(n,9)");
    QVERIFY2(!clip.isEmpty(), "ffmpeg could not make the test clip");
    DrivingOptions driving;  // Relative, neutral frame 0, the default smoothing.
    // The export: `animate`'s path, into a PNG sequence.
    RecordingSource exported;
    {
      RunContext ctx;
      std::unique_ptr<Driver> driver = OpenDriver(clip.toStdString(), DrivingAnalyzers({}), driving, ctx);
      AnimationPlan plan;
      plan.width = plan.height = 32;
      ExportOptions out;
      out.output = dir.filePath(QStringLiteral("frames")).toStdString();
      const ExportStats stats = ExportAnimation(exported, driver.get(), plan, out, ctx);
      QCOMPARE(stats.frames, int64_t{kFrames});
    }
    // The preview, played frame by frame, following the driver's pose, with the user's view
    // at rest.
    auto previewed = std::make_shared<RecordingSource>();
    PreviewWorker worker;
    worker.setSource(previewed);
    worker.setAnalyzerFactory(DrivingAnalyzers({}));
    WorkerSpy loaded(&worker, &PreviewWorker::driverLoaded);
    WorkerSpy frames(&worker, &PreviewWorker::frameReady);
    worker.loadDriver(clip, driving);
    QVERIFY(loaded.waitForCount(1, 60000));
    QCOMPARE(loaded.first().at(1).toLongLong(), qint64{kFrames});
    std::vector<bool> face;
    for (int i = 0; i < kFrames; ++i) {
      PreviewRequest r;
      r.frame.width = r.frame.height = 32;
      r.driver_frame = i;
      r.driver_pose = true;
      const quint64 serial = worker.request(r);
      QTRY_VERIFY_WITH_TIMEOUT(!frames.isEmpty() && frames.last().at(0).value<PreviewFrame>().serial == serial, 60000);
      face.push_back(frames.last().at(0).value<PreviewFrame>().driver_face_found);
    }
    QCOMPARE(static_cast<int>(previewed->requests.size()), kFrames);
    QCOMPARE(static_cast<int>(exported.requests.size()), kFrames);
    int moved = 0;
    for (int i = 0; i < kFrames; ++i) {
      const FrameRequest& a = exported.requests[i];
      const FrameRequest& b = previewed->requests[i];
      const bool blank = (i >= 3 && i <= 5) || i == 9;
      QVERIFY2(face[i] == !blank, qPrintable(QStringLiteral("frame %1: face_found %2").arg(i).arg(face[i])));
      QVERIFY2(a.view == b.view, qPrintable(QStringLiteral("frame %1: export yaw %2 pitch %3, preview yaw %4 pitch %5")
                                                .arg(i)
                                                .arg(a.view.yaw)
                                                .arg(a.view.pitch)
                                                .arg(b.view.yaw)
                                                .arg(b.view.pitch)));
      QVERIFY2(a.expression == b.expression, qPrintable(QStringLiteral("frame %1: expressions differ").arg(i)));
      QCOMPARE(static_cast<int>(a.expression.coefficients.size()), 12);
      for (float c : a.expression.coefficients) QVERIFY(std::isfinite(c));
      QVERIFY(std::isfinite(a.view.yaw) && std::isfinite(a.view.pitch) && std::isfinite(a.view.roll));
      if (i > 0 && !(a.view == exported.requests[0].view)) ++moved;
    }
    // Frame 0 is the neutral frame: the source's own pose, exactly.
    QCOMPARE(exported.requests[0].view.yaw, 6.0);
    QCOMPARE(exported.requests[0].view.pitch, -3.0);
    qInfo("%d frames: preview == export on all, %d of them away from the neutral pose", kFrames, moved);
    QVERIFY2(moved > 0, "the driver's head pose never reached the frames");
  }

  // A driver whose first 2 s show no face: the first frame with a face becomes the neutral
  // frame, and the worker says so; an out-of-range neutral frame is refused with a message.
  void aFacelessNeutralFrameIsReplacedAndReported() {
    const QString clip = LateClip();
    QVERIFY2(!clip.isEmpty(), "ffmpeg could not make the test clip");
    PreviewWorker worker;
    worker.setSource(std::make_shared<RecordingSource>());
    worker.setAnalyzerFactory(DrivingAnalyzers({}));
    WorkerSpy chosen(&worker, &PreviewWorker::drivingNeutralChosen);
    WorkerSpy loaded(&worker, &PreviewWorker::driverLoaded);
    WorkerSpy failed(&worker, &PreviewWorker::driverFailed);
    worker.loadDriver(clip, DrivingOptions{});
    QVERIFY(loaded.waitForCount(1, 60000));
    QCOMPARE(chosen.count(), 1);
    const qint64 frame = chosen.first().at(0).toLongLong();
    const QString note = chosen.first().at(1).toString();
    qInfo("neutral frame used: %lld (%s)", static_cast<long long>(frame), qPrintable(note));
    QVERIFY2(frame >= 20 && frame < 24, qPrintable(note));
    QVERIFY2(note.contains(QStringLiteral("neutral frame 0")) && note.contains(QStringLiteral("first frame with a face")),
             qPrintable(note));
    DrivingOptions past;
    past.neutral_frame = 24;
    worker.loadDriver(clip, past);
    QVERIFY(failed.waitForCount(1, 60000));
    QVERIFY2(failed.first().at(1).toString().contains(QStringLiteral("past the end")),
             qPrintable(failed.first().at(1).toString()));
  }

  // The studio window shows the driver's choice: in the status bar and in the driving panel's
  // neutral-frame box.
  void theStudioShowsTheNeutralFrameItUses() {
    const QString clip = LateClip();
    QVERIFY2(!clip.isEmpty(), "ffmpeg could not make the test clip");
    MainWindow w;
    w.setDialogsEnabled(false);
    QSignalSpy loaded(&w, &MainWindow::driverLoaded);  // emitted on the GUI thread
    w.openDriver(clip);
    QVERIFY(loaded.wait(60000));
    qInfo("status: %s", qPrintable(w.statusText()));
    QVERIFY2(w.statusText().contains(QStringLiteral("late.mp4 loaded")), qPrintable(w.statusText()));
    QVERIFY2(w.statusText().contains(QStringLiteral("first frame with a face")), qPrintable(w.statusText()));
    const int64_t used = w.drivingPanel()->options().neutral_frame;
    QVERIFY2(used >= 20 && used < 24, qPrintable(QString::number(used)));
    QVERIFY2(w.statusText().contains(QStringLiteral("using frame %1").arg(used)), qPrintable(w.statusText()));
  }

  // Live driving in the studio (issue 34). Without an avatar, and with a camera that does not
  // exist, a clear error and no session; a video played as a camera drives the morphable
  // preview: frames reach the viewport and the camera's frames the driving panel, the status
  // says live and what drives it, sliders do not interrupt, and when the clip ends the session
  // ends by itself with its summary and the sliders' frame comes back.
  void liveDrivesTheAvatarFromAVideoPlayedAsACamera() {
    MainWindow w;
    w.setDialogsEnabled(false);
    w.show();
    QVERIFY(QTest::qWaitForWindowExposed(&w));
    QVERIFY(!w.startLive(QStringLiteral("0")));
    QVERIFY2(w.lastError().contains(QStringLiteral("portrait first")), qPrintable(w.lastError()));
    QVERIFY(!w.isLive());

    w.sourcePanel()->morphablePreviewBox()->setChecked(true);  // the fast renderer
    QSignalSpy done(&w, &MainWindow::reconstructionFinished);
    const QString portrait =
        QString::fromStdString(DataPaths::Resolve().Require("samples/franck_01829.jpg", "a sample portrait").string());
    QVERIFY(w.openPortrait(portrait, false));
    QVERIFY(w.reconstruct());
    QVERIFY(done.wait(180000));

    QVERIFY(!w.startLive(QStringLiteral("/no/such/camera.mp4")));
    QVERIFY2(w.lastError().contains(QStringLiteral("camera.mp4")), qPrintable(w.lastError()));
    QVERIFY(!w.isLive());

    QTemporaryDir dir;
    const QString clip = MakeClip(dir, QStringLiteral("drive.mp4"), 30, "0");  // 3 s at 10 fps
    QVERIFY2(!clip.isEmpty(), "ffmpeg could not make the test clip");
    QSignalSpy frames(&w, &MainWindow::liveFrameShown);
    QSignalSpy ended(&w, &MainWindow::liveEnded);
    QVERIFY2(w.startLive(clip), qPrintable(w.lastError()));
    QVERIFY(w.isLive());
    QVERIFY2(w.statusText().startsWith(QStringLiteral("Live")), qPrintable(w.statusText()));
    QVERIFY(frames.wait(60000));
    w.expressionPanel()->resetToNeutral();  // a slider move while live: no preview request
    QVERIFY(ended.wait(60000));
    const QString summary = ended.first().at(0).toString();
    qInfo("live: %lld frames shown; %s", static_cast<long long>(frames.count()), qPrintable(summary));
    QVERIFY2(summary.contains(QStringLiteral("the video ended")), qPrintable(summary));
    QVERIFY(frames.count() >= 3);
    QVERIFY(!w.isLive());
    QVERIFY(!w.viewport()->image().isNull());
    QCOMPARE(w.viewport()->image().width(), 256);
    w.sourcePanel()->morphablePreviewBox()->setChecked(false);  // a persisted setting: restore it
  }

  // Stopping a live session (Esc, Driving > Stop Live) ends it at once: no frame after it, the
  // status says it stopped.
  void stoppingLiveEndsItAtOnce() {
    MainWindow w;
    w.setDialogsEnabled(false);
    w.sourcePanel()->morphablePreviewBox()->setChecked(true);
    QSignalSpy done(&w, &MainWindow::reconstructionFinished);
    const QString portrait =
        QString::fromStdString(DataPaths::Resolve().Require("samples/franck_01829.jpg", "a sample portrait").string());
    QVERIFY(w.openPortrait(portrait, false));
    QVERIFY(w.reconstruct());
    QVERIFY(done.wait(180000));
    const QString clip =
        QString::fromStdString(DataPaths::Resolve().Require("samples/cap13_edit2.mp4", "a sample clip").string());
    QSignalSpy frames(&w, &MainWindow::liveFrameShown);
    QSignalSpy ended(&w, &MainWindow::liveEnded);
    QVERIFY(w.startLive(clip));
    QVERIFY(frames.wait(60000));
    w.cancelJob();  // what Esc does
    QVERIFY(!w.isLive());
    const int shown = frames.count();
    QTest::qWait(500);
    QCOMPARE(frames.count(), shown);
    QVERIFY(ended.count() == 1 || ended.wait(5000));
    QVERIFY2(ended.first().at(0).toString().contains(QStringLiteral("stopped")), qPrintable(ended.first().at(0).toString()));
    w.sourcePanel()->morphablePreviewBox()->setChecked(false);  // a persisted setting: restore it
  }

  void badDriverIsReportedNotThrown() {
    PreviewWorker worker;
    WorkerSpy failed(&worker, &PreviewWorker::driverFailed);
    worker.loadDriver(QStringLiteral("/no/such/clip.mp4"), DrivingOptions{});
    QVERIFY(failed.waitForCount(1, 5000));
    QVERIFY(failed.first().at(1).toString().contains(QStringLiteral("clip.mp4")));
  }

 private:
  // 24 frames at 10 fps whose first 2 s (20 frames) are black, made once.
  QString LateClip() {
    if (late_clip_.isEmpty() && clip_dir_.isValid()) {
      late_clip_ = MakeClip(clip_dir_, QStringLiteral("late.mp4"), 24, "lt(n,20)");
    }
    return late_clip_;
  }

  QTemporaryDir model_dir_;
  QTemporaryDir clip_dir_;
  QString late_clip_;
};

}  // namespace avatar::ui

AVATAR_UI_TEST(preview_worker, avatar::ui::PreviewWorkerTest)
#include "preview_worker_test.moc"
