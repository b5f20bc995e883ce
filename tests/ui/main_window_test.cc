// Starts the real main window under Xvfb, opens the sample portrait through the drag and
// drop path, grabs the window and checks the portrait's pixels are in the viewport.
#include <QDropEvent>
#include <QScreen>
#include <QMimeData>
#include <QSettings>
#include <QSignalSpy>
#include <QStandardPaths>
#include <QTemporaryDir>
#include <QUrl>
#include <QtTest/QtTest>

#include <opencv2/imgproc.hpp>

#include "core/io/data_paths.h"
#include "core/io/image_io.h"
#include "core/pipeline/portrait_preview.h"
#include "ui/image_convert.h"
#include "ui/main_window.h"
#include "ui/studio.h"
#include "ui/viewport.h"

namespace avatar::ui {

class MainWindowTest : public QObject {
  Q_OBJECT

 private:
  // Sends the same events a desktop drag and drop does.
  static void DropFile(QWidget* target, const QString& path) {
    QMimeData mime;
    mime.setUrls({QUrl::fromLocalFile(path)});
    const QPoint at = target->rect().center();
    QDragEnterEvent enter(at, Qt::CopyAction, &mime, Qt::LeftButton, Qt::NoModifier);
    QApplication::sendEvent(target, &enter);
    QVERIFY2(enter.isAccepted(), "the window refused the dragged image");
    QDropEvent drop(QPointF(at), Qt::CopyAction, &mime, Qt::LeftButton, Qt::NoModifier);
    QApplication::sendEvent(target, &drop);
  }

 private slots:
  void initTestCase() {
    QStandardPaths::setTestModeEnabled(true);
    SetApplicationIdentity();
    QCoreApplication::setOrganizationName(QStringLiteral("AvatarStudioTest"));
    QSettings().clear();
  }

  void droppedPortraitIsVisibleInTheViewport() {
    const DataPaths data = DataPaths::Resolve();
    const QString portrait =
        QString::fromStdString(data.Require(DataPaths::kDefaultPortrait, "the sample portrait").string());

    MainWindow window;
    window.setDialogsEnabled(false);
    window.resize(1280, 720);
    window.show();
    QVERIFY(QTest::qWaitForWindowExposed(&window));

    QSignalSpy loaded(&window, &MainWindow::portraitLoaded);
    DropFile(&window, portrait);
    QCOMPARE(loaded.count(), 1);
    QVERIFY2(window.lastError().isEmpty(), qPrintable(window.lastError()));
    QTest::qWait(200);

    // Grab what the X server shows for the window: the real on-screen pixels, including
    // the OpenGL viewport (QWidget::grab() would re-render widgets instead).
    const QImage shot = window.screen()->grabWindow(window.winId()).toImage();
    if (qEnvironmentVariableIsSet("AVATAR_TEST_SAVE_SHOTS")) {
      shot.save(qEnvironmentVariable("AVATAR_TEST_SAVE_SHOTS") + "/main_window_portrait.png");
    }
    Viewport* vp = window.viewport();
    const QPoint origin = vp->mapTo(&window, QPoint(0, 0));
    const QRect vp_rect(origin, vp->size());
    QVERIFY(shot.rect().contains(vp_rect));
    const cv::Mat grabbed = ToMat(shot.copy(vp_rect));

    // What the viewport should show: the portrait letterboxed by the core's rule.
    const cv::Mat expected = LetterboxImage(LoadImageBgr(portrait.toStdString()), vp->width(), vp->height());
    QCOMPARE(grabbed.size(), expected.size());

    const QRect ir = vp->imageRect();
    const cv::Rect roi(ir.x(), ir.y(), ir.width(), ir.height());
    QVERIFY(roi.area() > 100 * 100);
    cv::Mat g, e;
    cv::cvtColor(grabbed(roi), g, cv::COLOR_BGR2GRAY);
    cv::cvtColor(expected(roi), e, cv::COLOR_BGR2GRAY);
    g.convertTo(g, CV_32F);
    e.convertTo(e, CV_32F);
    const double mean_abs = cv::mean(cv::abs(g - e))[0];
    cv::Mat gc = g - cv::mean(g)[0], ec = e - cv::mean(e)[0];
    const double corr = gc.dot(ec) / std::sqrt(gc.dot(gc) * ec.dot(ec) + 1e-9);
    qInfo("viewport vs portrait: mean abs grey difference %.2f, correlation %.4f", mean_abs, corr);
    QVERIFY2(corr > 0.95, "the viewport does not show the portrait");
    QVERIFY2(mean_abs < 12.0, "the viewport's pixels differ from the portrait");
    // Outside the image the viewport is black.
    if (roi.x > 4) QVERIFY(cv::norm(grabbed(cv::Rect(0, 0, 2, grabbed.rows)), cv::NORM_INF) < 10);

    QVERIFY(window.recentFiles().value(0).endsWith(QStringLiteral("grace_hopper.jpg")));
    QVERIFY(window.windowTitle().startsWith(QStringLiteral("grace_hopper.jpg")));
  }

  void badFileShowsAnErrorAndKeepsTheOldImage() {
    QTemporaryDir dir;
    const QString bad = dir.filePath(QStringLiteral("broken.jpg"));
    QFile f(bad);
    QVERIFY(f.open(QIODevice::WriteOnly));
    f.write("not a jpeg");
    f.close();
    cv::Mat red(20, 20, CV_8UC3, cv::Scalar(0, 0, 255));
    const QString good = dir.filePath(QStringLiteral("red.png"));
    SaveImage(good.toStdString(), red);

    MainWindow window;
    window.setDialogsEnabled(false);
    window.show();
    QVERIFY(QTest::qWaitForWindowExposed(&window));
    QVERIFY(window.openPortrait(good));
    QSignalSpy failed(&window, &MainWindow::portraitFailed);
    DropFile(&window, bad);
    QCOMPARE(failed.count(), 1);
    QVERIFY(window.lastError().contains(QStringLiteral("broken.jpg")));
    QCOMPARE(window.viewport()->image().pixelColor(5, 5), QColor(255, 0, 0));
  }

  void nonImageDropsAreRefused() {
    MainWindow window;
    window.show();
    QMimeData mime;
    mime.setUrls({QUrl::fromLocalFile(QStringLiteral("/tmp/notes.txt"))});
    QDragEnterEvent enter(QPoint(5, 5), Qt::CopyAction, &mime, Qt::LeftButton, Qt::NoModifier);
    QApplication::sendEvent(&window, &enter);
    QVERIFY(!enter.isAccepted());
  }

  void geometryPersists() {
    {
      MainWindow window;
      window.show();
      window.resize(900, 640);
      QVERIFY(QTest::qWaitForWindowExposed(&window));
      window.close();
    }
    MainWindow again;
    QCOMPARE(again.size(), QSize(900, 640));
  }
};

}  // namespace avatar::ui

QTEST_MAIN(avatar::ui::MainWindowTest)
#include "main_window_test.moc"
