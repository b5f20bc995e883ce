// Drives the real studio window under Xvfb through the main job: drop the sample portrait,
// reconstruct on the worker (the event loop keeps turning), load and scrub the sample
// driving clip, export 10 frames and verify the file, cancel an export and find nothing
// left. With AVATAR_TEST_SAVE_SHOTS=DIR it saves screenshots of the main states there.
// LibTorch (via the morphable model, in common/synthetic_studio.h) first: Qt's `slots` macro breaks its headers.
#include "common/synthetic_studio.h"
#include "core/pipeline/detail_source.h"
#include "core/pipeline/head_mesh.h"

#include <QAbstractButton>
#include <QAbstractSlider>
#include <QAction>
#include <QCheckBox>
#include <QComboBox>
#include <QDockWidget>
#include <QDropEvent>
#include <QElapsedTimer>
#include <QLabel>
#include <QMenuBar>
#include <QMimeData>
#include <QScreen>
#include <QSettings>
#include <QSignalSpy>
#include <QSlider>
#include <QSpinBox>
#include <QStandardPaths>
#include <QTemporaryDir>
#include <QUrl>
#include <QtTest/QtTest>

#include "ui_test_main.h"

#include <algorithm>
#include <filesystem>

#include <opencv2/imgproc.hpp>

#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/io/video_io.h"
#include "ui/image_convert.h"
#include "ui/job_runner.h"
#include "ui/main_window.h"
#include "ui/panels.h"
#include "ui/preview_worker.h"
#include "ui/studio.h"
#include "ui/viewport.h"

namespace avatar::ui {

// GL vs CPU frame of one camera (orbitDragRedrawsTheMeshesWithoutTheNetwork): the share of the
// CPU frame's opaque pixels the meshes draw, and the mean absolute difference there (grey levels).
// Measured with Mesa's llvmpipe at yaw 16-22 on the sample portrait: coverage 0.934-0.937, mean
// difference 12.6-12.7; the bounds leave room for another GL implementation's rasterisation.
constexpr double kGlCoverage = 0.85;
constexpr double kGlCpuDifference = 20.0;

class StudioTest : public QObject {
  Q_OBJECT

 private:
  static void DropFile(QWidget* target, const QString& path) {
    QMimeData mime;
    mime.setUrls({QUrl::fromLocalFile(path)});
    const QPoint at = target->rect().center();
    QDragEnterEvent enter(at, Qt::CopyAction, &mime, Qt::LeftButton, Qt::NoModifier);
    QApplication::sendEvent(target, &enter);
    QVERIFY2(enter.isAccepted(), qPrintable(QStringLiteral("the window refused ") + path));
    QDropEvent drop(QPointF(at), Qt::CopyAction, &mime, Qt::LeftButton, Qt::NoModifier);
    QApplication::sendEvent(target, &drop);
  }

  static void Shot(QWidget* window, const QString& name) {
    if (!qEnvironmentVariableIsSet("AVATAR_TEST_SAVE_SHOTS")) return;
    QTest::qWait(150);
    const QImage shot = window->screen()->grabWindow(window->winId()).toImage();
    QVERIFY(shot.save(qEnvironmentVariable("AVATAR_TEST_SAVE_SHOTS") + "/" + name + ".png"));
  }

  static QString Sample(const char* relative) {
    return QString::fromStdString(
        DataPaths::Resolve().Require(relative, "sample media for the studio test (run scripts/setup)").string());
  }

  // Turns the event loop until `done` (checked about every millisecond, unlike QTRY's 50 ms
  // steps, so that timings around it are not rounded up); false after `timeout_ms`.
  template <typename F>
  static bool SpinUntil(F done, int timeout_ms) {
    QElapsedTimer t;
    t.start();
    while (!done()) {
      if (t.elapsed() > timeout_ms) return false;
      QCoreApplication::processEvents(QEventLoop::AllEvents, 1);
      if (!done()) QThread::usleep(200);
    }
    return true;
  }

  // Waits until the viewport shows a frame answering a request made after this call.
  static bool WaitForFreshFrame(MainWindow& w, QSignalSpy& shown, int timeout_ms = 30000) {
    shown.clear();
    return shown.wait(timeout_ms);
  }

  std::unique_ptr<MainWindow> window_;
  QTemporaryDir out_dir_;
  QTemporaryDir model_dir_;

 private slots:
  void initTestCase() {
    const QString error = testing::UseSyntheticModelAndTestSettings(model_dir_);
    QVERIFY2(error.isEmpty(), qPrintable(error));
    window_ = std::make_unique<MainWindow>();
    window_->setDialogsEnabled(false);
    window_->resize(1280, 720);
    window_->show();
    QVERIFY(QTest::qWaitForWindowExposed(window_.get()));
    // Window shortcuts need the active window (Xvfb has no window manager to activate it).
    window_->activateWindow();
    QVERIFY(QTest::qWaitForWindowActive(window_.get()));
  }

  void cleanupTestCase() { window_.reset(); }

  void emptyWindowFitsAt1280x720WithTooltipsAndShortcuts() {
    MainWindow& w = *window_;
    QCOMPARE(w.size(), QSize(1280, 720));
    Shot(&w, QStringLiteral("studio-empty"));
    // Every dock and the viewport are visible and inside the window; the viewport is usable.
    for (QDockWidget* dock : w.findChildren<QDockWidget*>()) {
      QVERIFY2(dock->isVisible(), qPrintable(dock->windowTitle()));
      QVERIFY2(w.rect().contains(QRect(dock->mapTo(&w, QPoint(0, 0)), dock->size())), qPrintable(dock->windowTitle()));
    }
    QVERIFY(w.viewport()->width() >= 300 && w.viewport()->height() >= 250);
    qInfo("viewport at 1280x720: %dx%d", w.viewport()->width(), w.viewport()->height());
    // Tooltips on every control.
    int controls = 0;
    for (QWidget* c : w.findChildren<QWidget*>()) {
      const bool is_control = qobject_cast<QAbstractButton*>(c) || qobject_cast<QAbstractSlider*>(c) ||
                              qobject_cast<QComboBox*>(c) || qobject_cast<QAbstractSpinBox*>(c);
      if (!is_control || c->parentWidget() == nullptr) continue;
      if (c->inherits("QDockWidgetTitleButton") || c->inherits("QScrollBar") || c->inherits("QToolButton")) continue;
      ++controls;
      QVERIFY2(!c->toolTip().isEmpty(), qPrintable(QStringLiteral("no tooltip on ") + c->metaObject()->className() +
                                                   " '" + c->objectName() + "' " + c->property("text").toString()));
    }
    qInfo("%d controls, all with tooltips", controls);
    QVERIFY(controls > 25);
    // Keyboard shortcuts of the main actions.
    QStringList shortcuts;
    for (QAction* a : w.findChildren<QAction*>()) {
      if (!a->shortcut().isEmpty()) shortcuts << a->shortcut().toString();
    }
    for (const char* key : {"Ctrl+O", "Ctrl+Shift+O", "Ctrl+E", "Ctrl+R", "Esc", "Ctrl+N", "Ctrl+0", "Ctrl+L", "Ctrl+M",
                            "Space", "[", "]"}) {
      QVERIFY2(shortcuts.contains(QString::fromLatin1(key)), key);
    }
    // Sliders are reachable by keyboard (a mnemonic label or focus) and move with the arrows.
    QSlider* yaw = w.posePanel()->yawSlider();
    yaw->setFocus();
    QTest::keyClick(yaw, Qt::Key_Right);
    QCOMPARE(yaw->value(), 1);
    QTest::keyClick(yaw, Qt::Key_Left);
    QCOMPARE(yaw->value(), 0);
  }

  void droppedPortraitReconstructsOnTheWorker() {
    MainWindow& w = *window_;
    QSignalSpy done(&w, &MainWindow::reconstructionFinished);
    QSignalSpy failed(&w, &MainWindow::reconstructionFailed);
    int ticks_while_busy = 0;
    QTimer timer;
    connect(&timer, &QTimer::timeout, [&] { ticks_while_busy += w.jobRunner()->isBusy() ? 1 : 0; });
    timer.start(5);
    DropFile(&w, Sample(DataPaths::kDefaultPortrait));
    QVERIFY(w.jobRunner()->isBusy() || done.count() == 1);
    QVERIFY2(done.wait(120000) || done.count() == 1, qPrintable(w.lastError()));
    timer.stop();
    QCOMPARE(failed.count(), 0);
    qInfo("the GUI event loop turned %d times during reconstruction", ticks_while_busy);
    QVERIFY2(ticks_while_busy > 0, "the GUI thread blocked during reconstruction");
    QVERIFY(w.frameSource() != nullptr);
    QVERIFY(w.frameSource()->SupportsPose());
    QSignalSpy shown(&w, &MainWindow::frameShown);
    QVERIFY(shown.wait(30000) || !w.lastFrame().isNull());
    QVERIFY(!w.viewport()->label().isEmpty());
    QVERIFY(!w.lastFrame().isNull());
    // The default renderer is the bundled neural model, and the label says so.
    QVERIFY2(w.viewport()->label().contains(QStringLiteral("Neural avatar: bundled neural model")),
             qPrintable(w.viewport()->label()));
    Shot(&w, QStringLiteral("studio-neural"));
    if (qEnvironmentVariableIsSet("AVATAR_TEST_SAVE_SHOTS")) {
      // The quality ladder with this machine's estimates for the bundled model (measured at first
      // use or read from the cache), its popup open: the list is a window of its own, so the
      // screen is grabbed.
      if (!w.qualityEstimates().has_value() || !w.qualityEstimates()->Complete()) {
        QSignalSpy estimated(&w, &MainWindow::qualityEstimatesChanged);
        QVERIFY(estimated.wait(180000));
      }
      QVERIFY(w.qualityEstimates()->Complete());
      auto* ladder = w.findChild<QComboBox*>(QStringLiteral("qualityLadder"));
      QVERIFY(ladder != nullptr);
      ladder->showPopup();
      QTest::qWait(300);
      const QImage screen = w.screen()->grabWindow(0).toImage();
      const QRect area = QRect(w.geometry().topLeft(), QSize(760, 560)).intersected(screen.rect());
      QVERIFY(screen.copy(area).save(qEnvironmentVariable("AVATAR_TEST_SAVE_SHOTS") + "/studio-quality-ladder.png"));
      ladder->hidePopup();
    }
    {
      // The rendered head is a real frame: not blank, and its opacity covers part of the image only.
      const QImage frame = w.lastFrame().convertToFormat(QImage::Format_RGB888);
      const cv::Mat m(frame.height(), frame.width(), CV_8UC3, const_cast<uchar*>(frame.constBits()),
                      static_cast<size_t>(frame.bytesPerLine()));
      cv::Scalar mean, stddev;
      cv::meanStdDev(m, mean, stddev);
      qInfo("neural frame %dx%d: mean %.1f, std %.1f", frame.width(), frame.height(), mean[0], stddev[0]);
      QVERIFY(stddev[0] + stddev[1] + stddev[2] > 10.0);
    }
    // The morphable preview is an explicit, labelled mode; the rest of this test case uses it.
    w.sourcePanel()->morphablePreviewBox()->setChecked(true);
    done.clear();
    QVERIFY(w.reconstruct());
    QVERIFY2(done.wait(120000), qPrintable(w.lastError()));
    QVERIFY(shown.wait(30000) || !w.lastFrame().isNull());
    QVERIFY2(w.viewport()->label().contains(QStringLiteral("Preview: morphable model (chosen")),
             qPrintable(w.viewport()->label()));
    // The landmark overlay (Ctrl+L) draws the projected landmarks of the rendered head.
    QTest::keyClick(&w, Qt::Key_L, Qt::ControlModifier);
    QVERIFY(w.viewport()->showLandmarks());
    Shot(&w, QStringLiteral("studio-reconstructed"));
    QTest::keyClick(&w, Qt::Key_L, Qt::ControlModifier);
    QVERIFY(!w.viewport()->showLandmarks());
  }

  void yawSliderTurnsTheHeadInTheViewport() {
    MainWindow& w = *window_;
    QSignalSpy shown(&w, &MainWindow::frameShown);
    Viewport* vp = w.viewport();
    const QRect vp_rect(vp->mapTo(&w, QPoint(0, 0)), vp->size());
    const cv::Mat before = ToMat(w.screen()->grabWindow(w.winId()).toImage().copy(vp_rect));
    const QImage frame_before = w.lastFrame();
    w.posePanel()->yawSlider()->setValue(35);
    QVERIFY(WaitForFreshFrame(w, shown));
    QTRY_VERIFY_WITH_TIMEOUT(w.lastFrame() != frame_before, 30000);
    QTest::qWait(200);
    const cv::Mat after = ToMat(w.screen()->grabWindow(w.winId()).toImage().copy(vp_rect));
    cv::Mat diff;
    cv::absdiff(before, after, diff);
    const double mean = cv::mean(diff)[0] + cv::mean(diff)[1] + cv::mean(diff)[2];
    qInfo("yaw 0 -> 35 degrees: mean absolute change of the on-screen viewport %.2f", mean / 3);
    QVERIFY2(mean / 3 > 1.0, "the viewport did not change when the yaw slider moved");
    // A real mouse drag in the viewport orbits: 100 px to the left at 0.3 degrees per pixel
    // takes the yaw from 35 to 5 (the pose sliders follow) and renders the new view.
    const QSlider* yaw = w.posePanel()->yawSlider();
    const QSlider* pitch = w.posePanel()->pitchSlider();
    QCOMPARE(yaw->value(), 35);
    const QPoint grab = vp->rect().center();
    const QImage frame_at_35 = w.lastFrame();
    shown.clear();
    QTest::mousePress(vp, Qt::LeftButton, Qt::NoModifier, grab);
    for (int step = 1; step <= 5; ++step) QTest::mouseMove(vp, grab - QPoint(20 * step, 0));
    QTest::mouseRelease(vp, Qt::LeftButton, Qt::NoModifier, grab - QPoint(100, 0));
    QCOMPARE(yaw->value(), 5);
    QCOMPARE(pitch->value(), 0);
    QTRY_VERIFY_WITH_TIMEOUT(!shown.isEmpty() && w.lastFrame() != frame_at_35, 30000);
    // Dragging down tilts the head down: 50 px = -15 degrees of pitch.
    QTest::mousePress(vp, Qt::LeftButton, Qt::NoModifier, grab);
    QTest::mouseMove(vp, grab + QPoint(0, 50));
    QTest::mouseRelease(vp, Qt::LeftButton, Qt::NoModifier, grab + QPoint(0, 50));
    QCOMPARE(pitch->value(), -15);
    QCOMPARE(yaw->value(), 5);
    // A double-click (click, double-click, release, as a real mouse sends them) resets the view.
    QTest::mouseClick(vp, Qt::LeftButton, Qt::NoModifier, grab);
    QTest::mouseDClick(vp, Qt::LeftButton, Qt::NoModifier, grab);
    QTest::mouseRelease(vp, Qt::LeftButton, Qt::NoModifier, grab);
    QCOMPARE(yaw->value(), 0);
    QCOMPARE(pitch->value(), 0);
    QVERIFY(WaitForFreshFrame(w, shown));
  }

  void expressionSliderChangesOnlyTheFace() {
    MainWindow& w = *window_;
    QSignalSpy shown(&w, &MainWindow::frameShown);
    QTRY_VERIFY_WITH_TIMEOUT(w.previewWorker()->isIdle(), 30000);
    QTest::qWait(100);
    const cv::Mat before = ToMat(w.lastFrame());
    const QImage alpha_before = w.lastAlpha();
    QSlider* jaw = w.expressionPanel()->slider(QStringLiteral("jawOpen"));
    QVERIFY(jaw->isEnabled());
    jaw->setValue(100);
    QVERIFY(WaitForFreshFrame(w, shown));
    QTRY_VERIFY_WITH_TIMEOUT(w.previewWorker()->isIdle(), 30000);
    QTest::qWait(100);
    const cv::Mat after = ToMat(w.lastFrame());
    QCOMPARE(after.size(), before.size());
    const cv::Mat a0(alpha_before.height(), alpha_before.width(), CV_8UC1, const_cast<uchar*>(alpha_before.constBits()),
                     static_cast<size_t>(alpha_before.bytesPerLine()));
    const QImage alpha_after = w.lastAlpha();
    const cv::Mat a1(alpha_after.height(), alpha_after.width(), CV_8UC1, const_cast<uchar*>(alpha_after.constBits()),
                     static_cast<size_t>(alpha_after.bytesPerLine()));
    cv::Mat diff;
    cv::absdiff(before, after, diff);
    cv::cvtColor(diff, diff, cv::COLOR_BGR2GRAY);
    const cv::Mat changed = diff > 3;
    const cv::Mat face = (a0 > 0) | (a1 > 0);
    const int inside = cv::countNonZero(changed & face);
    const int outside = cv::countNonZero(changed & ~face);
    qInfo("jawOpen 0 -> 1: %d pixels changed inside the face, %d outside", inside, outside);
    QVERIFY2(inside > 200, "the expression slider did not change the face");
    QCOMPARE(outside, 0);
    // Ctrl+N (Neutral) resets every control.
    QTest::keyClick(&w, Qt::Key_N, Qt::ControlModifier);
    QCOMPARE(jaw->value(), 0);
  }

  // Issue 34: with the detail path an orbit drag is a redraw of the avatar's meshes with OpenGL,
  // not a render: the network is not called while dragging, the full frame follows on release,
  // and the GL picture agrees with that CPU frame of the same camera. With
  // AVATAR_TEST_ORBIT_SECONDS=10 it is the GUI measurement of docs/PERFORMANCE.md (time from each
  // drag step's mouse event to the viewport's swapped frame); timings are printed, not judged.
  void orbitDragRedrawsTheMeshesWithoutTheNetwork() {
    MainWindow& w = *window_;
    QSignalSpy done(&w, &MainWindow::reconstructionFinished);
    QSignalSpy shown(&w, &MainWindow::frameShown);
    w.sourcePanel()->morphablePreviewBox()->setChecked(false);
    QVERIFY(w.reconstruct());
    QVERIFY2(done.wait(120000), qPrintable(w.lastError()));
    Viewport* vp = w.viewport();
    // The issue's viewport: a 512 x 512 picture.
    w.resize(1600, 900);
    vp->setFixedSize(512, 512);
    QTRY_VERIFY_WITH_TIMEOUT(vp->imageRect().width() == 512, 10000);
    QTRY_VERIFY_WITH_TIMEOUT(vp->hasScene(), 60000);
    QTRY_VERIFY_WITH_TIMEOUT(w.previewWorker()->isIdle() && !w.lastFrame().isNull(), 30000);
    const auto* detail = DetailFrameSource::Find(w.frameSource().get());
    QVERIFY(detail != nullptr);
    {
      // What the worker built once for this avatar, built again here to time it.
      RunContext ctx;
      QElapsedTimer t;
      t.start();
      const std::shared_ptr<const HeadMesh> meshes = detail->ViewportMesh(ctx);
      size_t triangles = 0;
      for (const TexturedMesh& part : meshes->parts) triangles += part.triangles.size();
      qInfo("viewport meshes: %zu parts, %zu triangles, built in %.0f ms", meshes->parts.size(), triangles,
            static_cast<double>(t.nsecsElapsed()) / 1e6);
      QVERIFY(meshes->parts.size() >= 2);
    }
    const int64_t base_before = detail->counts().base_renders;
    const quint64 rendered_before = w.previewWorker()->framesRendered();
    const quint64 mesh_before = w.meshOrbitFrames();
    QSignalSpy swapped(vp, &QOpenGLWidget::frameSwapped);
    const double seconds = qEnvironmentVariableIsSet("AVATAR_TEST_ORBIT_SECONDS")
                               ? qEnvironmentVariable("AVATAR_TEST_ORBIT_SECONDS").toDouble()
                               : 1.0;
    const QPoint grab = vp->rect().center();
    QTest::mousePress(vp, Qt::LeftButton, Qt::NoModifier, grab);
    std::vector<double> ms;
    QElapsedTimer total;
    total.start();
    int offset = 0, direction = 1;
    while (total.elapsed() < seconds * 1000.0) {
      // Back and forth across yaw -30..+30 degrees, 4 px (1.2 degrees) per step.
      offset += 4 * direction;
      if (std::abs(offset) >= 100) direction = -direction;
      const int frames = static_cast<int>(swapped.count());
      QElapsedTimer step;
      step.start();
      QTest::mouseMove(vp, grab + QPoint(offset, 0));
      QVERIFY(SpinUntil([&] { return swapped.count() > frames; }, 10000));
      ms.push_back(static_cast<double>(step.nsecsElapsed()) / 1e6);
    }
    if (qEnvironmentVariableIsSet("AVATAR_TEST_SAVE_SHOTS")) {
      // Frames of a drag across -30..+30 degrees for the README's GIF (orbit-NNN.png).
      for (int i = 0; i < 48; ++i) {
        const int x = i < 24 ? -100 + i * 200 / 23 : 100 - (i - 24) * 200 / 23;
        QTest::mouseMove(vp, grab + QPoint(x, 0));
        const QImage picture = vp->grabPicture().copy(vp->imageRect());
        QVERIFY(picture.save(qEnvironmentVariable("AVATAR_TEST_SAVE_SHOTS") +
                             QStringLiteral("/orbit-%1.png").arg(i, 3, 10, QLatin1Char('0'))));
      }
    }
    QTest::mouseMove(vp, grab + QPoint(60, 0));  // about yaw +18 for the comparison below
    QTRY_VERIFY_WITH_TIMEOUT(vp->showingScene(), 5000);
    // The pose panel keeps whole degrees, so 1.2 degree steps drift: a turned view, whichever.
    QVERIFY2(w.posePanel()->yawSlider()->value() >= 5 && w.posePanel()->yawSlider()->value() <= 35,
             qPrintable(QString::number(w.posePanel()->yawSlider()->value())));
    const QImage gl_picture = vp->grabPicture();
    std::vector<double> sorted = ms;
    std::sort(sorted.begin(), sorted.end());
    const auto at = [&](double q) { return sorted[static_cast<size_t>(q * static_cast<double>(sorted.size() - 1))]; };
    qInfo("orbit drag, %.1f s at %dx%d (picture %dx%d): %zu steps, mouse event to swapped frame median %.1f ms, "
          "p95 %.1f ms, max %.1f ms; GL draw %.2f ms",
          seconds, vp->width(), vp->height(), vp->imageRect().width(), vp->imageRect().height(), ms.size(), at(0.5),
          at(0.95), sorted.back(), vp->lastSceneMilliseconds());
    QVERIFY(!ms.empty());
    // A camera move did not call the network or the preview's renderer: the meshes drew every step.
    QCOMPARE(detail->counts().base_renders, base_before);
    QCOMPARE(w.previewWorker()->framesRendered(), rendered_before);
    QVERIFY(w.meshOrbitFrames() >= mesh_before + ms.size());
    QVERIFY(w.frameTimeText().contains(QStringLiteral("OpenGL")));
    // On release the full frame of the same camera follows and replaces the meshes.
    shown.clear();
    QTest::mouseRelease(vp, Qt::LeftButton, Qt::NoModifier, grab + QPoint(60, 0));
    QVERIFY(shown.wait(60000));
    QTRY_VERIFY_WITH_TIMEOUT(!vp->showingScene(), 5000);
    QCOMPARE(detail->counts().base_renders, base_before + 1);
    // GL vs CPU over the CPU frame's opaque pixels: same camera, same photo, so the pictures line up.
    cv::Mat gl = ToMat(gl_picture.copy(vp->imageRect()));
    const cv::Mat cpu = ToMat(w.lastFrame());
    cv::resize(gl, gl, cpu.size(), 0, 0, cv::INTER_AREA);
    const QImage alpha_image = w.lastAlpha();
    const cv::Mat alpha(alpha_image.height(), alpha_image.width(), CV_8UC1, const_cast<uchar*>(alpha_image.constBits()),
                        static_cast<size_t>(alpha_image.bytesPerLine()));
    cv::Mat opaque = alpha > 128, gl_gray;
    cv::cvtColor(gl, gl_gray, cv::COLOR_BGR2GRAY);
    const double covered = static_cast<double>(cv::countNonZero(opaque & (gl_gray > 8))) /
                           std::max(1, cv::countNonZero(opaque));
    cv::Mat diff;
    cv::absdiff(gl, cpu, diff);
    const cv::Scalar mean = cv::mean(diff, opaque & (gl_gray > 8));
    const double mad = (mean[0] + mean[1] + mean[2]) / 3.0;
    qInfo("GL meshes vs CPU detail frame at yaw %d: the meshes cover %.3f of the frame's opaque pixels, mean "
          "absolute difference %.2f grey levels there",
          w.posePanel()->yawSlider()->value(), covered, mad);
    if (qEnvironmentVariableIsSet("AVATAR_TEST_SAVE_SHOTS")) {
      cv::Mat both;
      cv::hconcat(gl, cpu, both);
      SaveImage(qEnvironmentVariable("AVATAR_TEST_SAVE_SHOTS").toStdString() + "/orbit-gl-vs-cpu.png", both);
    }
    QVERIFY2(covered > kGlCoverage, "the GL meshes leave much of the head undrawn");
    QVERIFY2(mad < kGlCpuDifference, "the GL picture differs from the CPU frame of the same camera");
    // Expression sliders in the running GUI (issue 34): from the slider's change to the first
    // updated frame swapped onto the screen (the quick frame: the photo's face at the new expression over the
    // kept network frame) and to the refined full frame, over a sweep of three controls; one
    // network render per change. Timings printed, not judged.
    std::vector<double> first_ms, refined_ms;
    QSignalSpy quick(&w, &MainWindow::quickFrameShown);
    for (const char* name : {"jawOpen", "smile", "blinkLeft"}) {
      QSlider* slider = w.expressionPanel()->slider(QString::fromLatin1(name));
      QVERIFY2(slider != nullptr && slider->isEnabled(), name);
      for (const int value : {50, 100, 0}) {
        QTRY_VERIFY_WITH_TIMEOUT(w.previewWorker()->isIdle(), 30000);
        quick.clear();
        shown.clear();
        const int64_t base = detail->counts().base_renders;
        QElapsedTimer t;
        t.start();
        slider->setValue(value);
        QVERIFY(SpinUntil([&] { return !quick.isEmpty() || !shown.isEmpty(); }, 30000));
        QVERIFY2(!quick.isEmpty(), "an expression change showed its full frame first");
        int swaps = static_cast<int>(swapped.count());
        QVERIFY(SpinUntil([&] { return swapped.count() > swaps; }, 5000));  // on screen
        first_ms.push_back(static_cast<double>(t.nsecsElapsed()) / 1e6);
        QVERIFY(SpinUntil([&] { return !shown.isEmpty(); }, 30000));
        swaps = static_cast<int>(swapped.count());
        QVERIFY(SpinUntil([&] { return swapped.count() > swaps; }, 5000));
        refined_ms.push_back(static_cast<double>(t.nsecsElapsed()) / 1e6);
        QCOMPARE(detail->counts().base_renders, base + 1);
      }
    }
    std::sort(first_ms.begin(), first_ms.end());
    std::sort(refined_ms.begin(), refined_ms.end());
    qInfo("expression sliders (jawOpen, smile, blinkLeft; 9 changes) at 512: slider change to the first updated frame "
          "shown median %.1f ms (max %.1f), to the refined frame median %.1f ms (max %.1f)",
          first_ms[first_ms.size() / 2], first_ms.back(), refined_ms[refined_ms.size() / 2], refined_ms.back());
    // Back to the morphable preview for the rest of this test case.
    done.clear();
    w.sourcePanel()->morphablePreviewBox()->setChecked(true);
    QVERIFY(w.reconstruct());
    QVERIFY2(done.wait(120000), qPrintable(w.lastError()));
    QTRY_VERIFY_WITH_TIMEOUT(!vp->hasScene(), 30000);
    vp->setMinimumSize(256, 256);
    vp->setMaximumSize(QWIDGETSIZE_MAX, QWIDGETSIZE_MAX);
    w.resize(1280, 720);
  }

  void droppedVideoBecomesTheDriverAndScrubs() {
    MainWindow& w = *window_;
    QSignalSpy loaded(&w, &MainWindow::driverLoaded);
    QSignalSpy shown(&w, &MainWindow::frameShown);
    DropFile(&w, Sample("samples/cap13_edit2.mp4"));
    QVERIFY(loaded.wait(30000));
    const VideoInfo info = VideoReader(Sample("samples/cap13_edit2.mp4").toStdString()).Info();
    QCOMPARE(w.drivingPanel()->frameCount(), static_cast<qint64>(info.frame_count));
    QTRY_VERIFY_WITH_TIMEOUT(w.lastDriverFrame() == 0, 30000);
    // Scrub on the timeline.
    w.drivingPanel()->timeline()->setValue(400);
    QTRY_VERIFY_WITH_TIMEOUT(w.lastDriverFrame() == 400, 30000);
    w.drivingPanel()->timeline()->setValue(120);
    QTRY_VERIFY_WITH_TIMEOUT(w.lastDriverFrame() == 120, 30000);
    // Play advances the timeline; Space (the shortcut) pauses.
    w.drivingPanel()->setPlaying(true);
    QTRY_VERIFY_WITH_TIMEOUT(w.drivingPanel()->currentFrame() >= 123, 30000);
    QTest::keyClick(&w, Qt::Key_Space);
    QVERIFY(!w.drivingPanel()->isPlaying());
    Shot(&w, QStringLiteral("studio-driving"));
  }

  // The Live source on the neural avatar with the photo's detail (issue 34): the sample clip
  // played as a camera drives it; frames arrive, the status bar says live, Stop Live ends it.
  void liveDrivesTheNeuralAvatar() {
    MainWindow& w = *window_;
    QSignalSpy done(&w, &MainWindow::reconstructionFinished);
    w.sourcePanel()->morphablePreviewBox()->setChecked(false);
    QVERIFY(w.reconstruct());
    QVERIFY2(done.wait(120000), qPrintable(w.lastError()));
    QVERIFY2(w.viewport()->label().contains(QStringLiteral("detail")), qPrintable(w.viewport()->label()));
    QSignalSpy frames(&w, &MainWindow::liveFrameShown);
    QVERIFY2(w.startLive(Sample("samples/cap13_edit2.mp4")), qPrintable(w.lastError()));
    QTRY_VERIFY_WITH_TIMEOUT(frames.count() >= 8, 60000);
    QVERIFY(w.isLive());
    {
      // Frames delivered over 5 s in the running studio (printed, not judged).
      const int before = static_cast<int>(frames.count());
      QElapsedTimer t;
      t.start();
      QTest::qWait(5000);
      qInfo("studio live: %.1f fps delivered over %.1f s at 256 px (%s)",
            (frames.count() - before) / (static_cast<double>(t.elapsed()) / 1000.0), t.elapsed() / 1000.0,
            qPrintable(w.frameTimeText()));
    }
    Shot(&w, QStringLiteral("studio-live"));
    QSignalSpy back(&w, &MainWindow::frameShown);
    w.stopLive();
    QVERIFY(!w.isLive());
    QVERIFY(back.wait(60000));  // the sliders' frame again
    QCOMPARE(w.viewport()->image().width(), 512);
    // Back to the morphable preview for the rest of this test case.
    done.clear();
    w.sourcePanel()->morphablePreviewBox()->setChecked(true);
    QVERIFY(w.reconstruct());
    QVERIFY2(done.wait(120000), qPrintable(w.lastError()));
  }

  void exportsTenFramesOfTheDrivenAvatar() {
    MainWindow& w = *window_;
    QVERIFY(out_dir_.isValid());
    const QString target = out_dir_.filePath(QStringLiteral("ten.mp4"));
    ExportOptions out;
    out.output = target.toStdString();
    AnimationPlan plan;
    plan.width = plan.height = 128;
    plan.max_frames = 10;
    QSignalSpy finished(&w, &MainWindow::exportFinished);
    QSignalSpy failed(&w, &MainWindow::exportFailed);
    QVERIFY(w.startExport(out, plan));
    QVERIFY2(finished.wait(120000), qPrintable(w.lastError()));
    QCOMPARE(failed.count(), 0);
    QCOMPARE(finished.first().at(1).toLongLong(), qint64{10});
    VideoReader reader(target.toStdString());
    QCOMPARE(reader.Info().frame_count, int64_t{10});
    QCOMPARE(reader.Info().width, 128);
    QCOMPARE(reader.Info().fps, VideoReader(Sample("samples/cap13_edit2.mp4").toStdString()).Info().fps);
    cv::Mat first;
    QVERIFY(reader.Read(first));
    QVERIFY(cv::norm(first, cv::NORM_INF) > 0);  // Not an empty black clip.
  }

  void cancelledExportLeavesNothing() {
    MainWindow& w = *window_;
    QTemporaryDir dir;
    const QString target = dir.filePath(QStringLiteral("long.mp4"));
    ExportOptions out;
    out.output = target.toStdString();
    AnimationPlan plan;  // The whole clip at 512x512: long enough to cancel.
    QSignalSpy cancelled(&w, &MainWindow::exportCancelled);
    QSignalSpy progress(w.jobRunner(), &JobRunner::progress);
    QVERIFY(w.startExport(out, plan));
    // Wait until frames are being written, then cancel.
    QTRY_VERIFY_WITH_TIMEOUT(!progress.isEmpty() && progress.last().at(0).toString() == QStringLiteral("export") &&
                                 progress.last().at(1).toDouble() > 0.02,
                             60000);
    Shot(&w, QStringLiteral("studio-exporting"));
    QElapsedTimer clock;
    clock.start();
    QTest::keyClick(&w, Qt::Key_Escape);  // The Cancel shortcut.
    QVERIFY(cancelled.wait(30000));
    qInfo("export cancel took effect after %lld ms", static_cast<long long>(clock.elapsed()));
    QVERIFY(QDir(dir.path()).entryList(QDir::AllEntries | QDir::Hidden | QDir::NoDotAndDotDot).isEmpty());
  }

  void randomWeightsAreExplicitAndLabelled() {
    MainWindow& w = *window_;
    QVERIFY(!w.sourcePanel()->randomWeights());  // Off by default, never persisted.
    QVERIFY(!w.viewport()->label().contains(QStringLiteral("RANDOM")));
    w.sourcePanel()->randomWeightsBox()->setChecked(true);
    QSignalSpy done(&w, &MainWindow::reconstructionFinished);
    QSignalSpy shown(&w, &MainWindow::frameShown);
    QTest::keyClick(&w, Qt::Key_R, Qt::ControlModifier);  // Reconstruct.
    QVERIFY2(done.wait(120000), qPrintable(w.lastError()));
    QVERIFY(WaitForFreshFrame(w, shown, 60000));
    QVERIFY2(w.viewport()->label().contains(QStringLiteral("RANDOM")), qPrintable(w.viewport()->label()));
    QVERIFY(w.viewport()->label().contains(QStringLiteral("not a result")));
    w.sourcePanel()->randomWeightsBox()->setChecked(false);
    QVERIFY(w.reconstruct());
    QVERIFY(done.wait(120000));
    QVERIFY(w.viewport()->label().contains(QStringLiteral("morphable model")));
  }

  void settingsPersist() {
    window_->sourcePanel()->setConfig(QStringLiteral("paper"));
    // The status bar names the network size (issue 31: not "preset").
    const auto* size_label = window_->findChild<QLabel*>(QStringLiteral("networkSizeLabel"));
    QVERIFY(size_label != nullptr);
    QCOMPARE(size_label->text(), QStringLiteral("Network size: paper"));
    window_->close();
    MainWindow again;
    QCOMPARE(again.sourcePanel()->config(), QStringLiteral("paper"));
    QCOMPARE(again.size(), QSize(1280, 720));
    again.sourcePanel()->setConfig(QStringLiteral("lite"));
  }
};

}  // namespace avatar::ui

AVATAR_UI_TEST(studio, avatar::ui::StudioTest)
#include "studio_test.moc"
