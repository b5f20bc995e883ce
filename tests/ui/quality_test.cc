// The quality ladder in the studio, on a tiny random-weight checkpoint under Xvfb: before the
// first use every level says "not measured yet"; picking `fine` and reconstructing the sample
// portrait runs the refinement on the job worker (its progress reaches the window), measures the
// ladder once (every entry then shows its estimates, cached for the next window) and shows a
// refined avatar; a `best` reconstruction can be cancelled during its refinement and leaves the
// previous avatar in place. (The screenshot of the ladder with the bundled model's estimates is
// taken by studio_test.)
// LibTorch (via the morphable model and the checkpoint writer) first: Qt's `slots` macro breaks its headers.
#include "common/synthetic_studio.h"
#include "core/model/checkpoint.h"
#include "core/model/goha_model.h"
#include "core/pipeline/detail_source.h"

#include <QCheckBox>
#include <QComboBox>
#include <QDockWidget>
#include <QElapsedTimer>
#include <QFile>
#include <QScreen>
#include <QSignalSpy>
#include <QTemporaryDir>
#include <QtTest/QtTest>

#include "ui_test_main.h"

#include <nlohmann/json.hpp>

#include "core/io/data_paths.h"
#include "core/pipeline/quality.h"
#include "core/pipeline/session_source.h"
#include "ui/job_runner.h"
#include "ui/main_window.h"
#include "ui/panels.h"

namespace avatar::ui {

class QualityTest : public QObject {
  Q_OBJECT

 private:
  QTemporaryDir model_dir_;
  QTemporaryDir work_;
  QString checkpoint_;

  static QString Sample(const char* relative) {
    return QString::fromStdString(
        DataPaths::Resolve().Require(relative, "sample portrait for the quality test (run scripts/setup)").string());
  }

  static std::unique_ptr<MainWindow> Window(const QString& checkpoint) {
    auto w = std::make_unique<MainWindow>();
    w->setDialogsEnabled(false);
    w->setReconstructOnOpen(false);
    w->setCheckpoint(checkpoint);
    w->resize(1280, 720);
    w->show();
    return w;
  }

  static QStringList Items(QComboBox* box) {
    QStringList items;
    for (int i = 0; i < box->count(); ++i) items << box->itemText(i);
    return items;
  }

  static const SessionFrameSource* Neural(const MainWindow& w) {
    // The neural avatar under the photo's detail path (the default) or shown alone.
    if (w.frameSource() == nullptr) return nullptr;
    return dynamic_cast<const SessionFrameSource*>(&Unwrapped(*w.frameSource()));
  }

 private slots:
  void initTestCase() {
    const QString error = testing::UseSyntheticModelAndTestSettings(model_dir_);
    QVERIFY2(error.isEmpty(), qPrintable(error));
    QVERIFY(work_.isValid());
    torch::manual_seed(11);
    GohaModel model(ModelConfig::Tiny());
    CheckpointInfo info;
    info.data_provenance = "random init (quality ladder ui test)";
    checkpoint_ = work_.filePath(QStringLiteral("tiny.ckpt"));
    SaveModelCheckpoint(checkpoint_.toStdString(), model, info);
  }

  // Each test function starts without estimates, in a cache of its own (never the user's data
  // folder), so that none depends on what another measured or on the order they run in.
  void init() {
    const QString cache = work_.filePath(QStringLiteral("quality-estimates-%1.json")
                                             .arg(QString::fromLatin1(QTest::currentTestFunction())));
    QFile::remove(cache);
    qputenv("AVATAR_QUALITY_CACHE", cache.toLocal8Bit());
  }

  void refinedReconstructionWithProgressAndMeasuredLadder() {
    auto w = Window(checkpoint_);
    QVERIFY(QTest::qWaitForWindowExposed(w.get()));
    QComboBox* ladder = w->sourcePanel()->qualityBox();
    QCOMPARE(ladder->count(), static_cast<int>(QualityLadder().size()));
    for (const QString& item : Items(ladder)) QVERIFY2(item.contains(QStringLiteral("not measured yet")), qPrintable(item));
    QVERIFY(!w->qualityEstimates().has_value());

    // The user picks `fine` (30 refinement steps) in the ladder.
    ladder->setCurrentIndex(ladder->findData(QStringLiteral("fine")));
    QCOMPARE(w->sourcePanel()->quality(), QStringLiteral("fine"));
    QVERIFY(w->openPortrait(Sample(DataPaths::kDefaultPortrait), false));

    QStringList stages;
    QStringList refine_messages;
    double last_refine_fraction = -1.0;
    bool refine_fraction_grows = true;
    connect(w->jobRunner(), &JobRunner::progress, this,
            [&](const QString& stage, double fraction, const QString& message) {
              if (!stages.contains(stage)) stages << stage;
              if (stage == QStringLiteral("refine")) {
                refine_messages << message;
                if (fraction < last_refine_fraction) refine_fraction_grows = false;
                last_refine_fraction = fraction;
              }
            });
    QSignalSpy done(w.get(), &MainWindow::reconstructionFinished);
    QSignalSpy failed(w.get(), &MainWindow::reconstructionFailed);
    QSignalSpy estimates(w.get(), &MainWindow::qualityEstimatesChanged);
    QVERIFY(w->reconstruct());
    QVERIFY2(done.wait(280000), qPrintable(w->lastError()));
    QCOMPARE(failed.count(), 0);
    qInfo("job stages: %s", qPrintable(stages.join(QStringLiteral(" | "))));

    // Refinement progress reached the window, step by step.
    QVERIFY2(stages.contains(QStringLiteral("refine")), qPrintable(stages.join(QStringLiteral(", "))));
    QVERIFY2(refine_messages.size() >= 2, qPrintable(refine_messages.join(QStringLiteral(", "))));
    QVERIFY(refine_fraction_grows);
    QVERIFY2(refine_messages.filter(QStringLiteral("/30")).size() > 0, qPrintable(refine_messages.join(", ")));
    QVERIFY2(stages.contains(QStringLiteral("measure quality ladder")), qPrintable(stages.join(QStringLiteral(", "))));

    // The avatar shown is the refined one.
    const SessionFrameSource* neural = Neural(*w);
    QVERIFY2(neural != nullptr, "the viewport does not show the neural avatar");
    const std::string info = neural->avatar().RefinementInfo();
    QVERIFY2(!info.empty(), "the avatar was not refined");
    const nlohmann::json refined = nlohmann::json::parse(info);
    QCOMPARE(refined["steps"].get<int>(), 30);
    QVERIFY(refined["psnr_after"].get<double>() >= refined["psnr_before"].get<double>());
    QVERIFY2(QString::fromStdString(neural->Label()).contains(QStringLiteral("refined on the photo")),
             qPrintable(QString::fromStdString(neural->Label())));

    // The ladder now shows this machine's estimates beside every level.
    QVERIFY(estimates.count() >= 1);
    QVERIFY(w->qualityEstimates().has_value());
    QVERIFY(w->qualityEstimates()->Complete());
    for (const QString& item : Items(ladder)) {
      QVERIFY2(item.contains(QStringLiteral("reconstruct ~")) && item.contains(QStringLiteral("frame ")),
               qPrintable(item));
    }
    const QualityEstimate* fine = w->qualityEstimates()->Find("fine");
    QVERIFY(fine != nullptr);
    QVERIFY(ladder->itemText(ladder->findData(QStringLiteral("fine"))).contains(QString::fromStdString(FormatQualityEstimate(fine))));


    // A new window reads the cached estimates without measuring.
    auto again = Window(checkpoint_);
    QVERIFY(again->qualityEstimates().has_value());
    QCOMPARE(again->qualityEstimates()->Find("fine")->frame_seconds, fine->frame_seconds);
  }

  void cancelDuringRefinementKeepsThePreviousAvatar() {
    auto w = Window(checkpoint_);
    QVERIFY(QTest::qWaitForWindowExposed(w.get()));
    w->sourcePanel()->setQuality(QStringLiteral("standard"));
    QVERIFY(w->openPortrait(Sample(DataPaths::kDefaultPortrait), false));
    QSignalSpy done(w.get(), &MainWindow::reconstructionFinished);
    QVERIFY(w->reconstruct());
    QVERIFY2(done.wait(280000), qPrintable(w->lastError()));
    const SessionFrameSource* before = Neural(*w);
    QVERIFY(before != nullptr);
    QVERIFY(before->avatar().RefinementInfo().empty());  // standard: one-shot planes
    // The studio's detail switch: on by default, off shows the same neural avatar alone at once
    // (no reconstruction), on again restores the detail path.
    QVERIFY(w->sourcePanel()->photoDetail());
    const std::shared_ptr<const FrameSource> with_detail = w->frameSource();
    // (finished by the bundled fusion net, as every head detail frame is by default)
    QVERIFY2(QString::fromStdString(with_detail->Label())
                 .contains(QString::fromStdString(DetailLabel("head") + ", finished by the fusion net (step ")),
             with_detail->Label().c_str());
    w->sourcePanel()->photoDetailBox()->setChecked(false);
    QCOMPARE(static_cast<const FrameSource*>(Neural(*w)), w->frameSource().get());
    QVERIFY(!QString::fromStdString(w->frameSource()->Label()).contains(QString::fromUtf8(kDetailLabel)));
    QVERIFY(!w->sourcePanel()->learnedFinishBox()->isEnabled());  // the finish is the detail's
    w->sourcePanel()->photoDetailBox()->setChecked(true);
    QCOMPARE(w->frameSource(), with_detail);
    QCOMPARE(Neural(*w), before);
    // The "Learned finish" switch: off shows the geometric composite over the same network
    // source at once, on the bundled net again.
    QVERIFY(w->sourcePanel()->learnedFinishBox()->isEnabled());
    QVERIFY(w->sourcePanel()->learnedFinish());
    w->sourcePanel()->learnedFinishBox()->setChecked(false);
    const std::string geometric = w->frameSource()->Label();
    QVERIFY2(QString::fromStdString(geometric).endsWith(QString::fromStdString(DetailLabel("head"))), geometric.c_str());
    QCOMPARE(Neural(*w), before);
    QCOMPARE(w->frameSource()->Wrapped(), with_detail->Wrapped());
    w->sourcePanel()->learnedFinishBox()->setChecked(true);
    QCOMPARE(w->frameSource()->Label(), with_detail->Label());
    QCOMPARE(Neural(*w), before);
    // That first use of the model measured the ladder (this test's cache started empty), so the
    // `best` reconstruction below refines and then has nothing left to measure.
    QVERIFY(w->qualityEstimates().has_value());

    w->sourcePanel()->setQuality(QStringLiteral("best"));
    bool refining = false;
    connect(w->jobRunner(), &JobRunner::progress, this, [&](const QString& stage, double, const QString&) {
      if (stage == QStringLiteral("refine")) refining = true;
    });
    QSignalSpy cancelled(w->jobRunner(), &JobRunner::cancelled);
    QVERIFY(w->reconstruct());
    QVERIFY(QTest::qWaitFor([&] { return refining; }, 280000));
    QElapsedTimer clock;
    clock.start();
    w->cancelJob();
    QVERIFY(cancelled.wait(60000));
    qInfo("refinement cancel took effect after %lld ms", static_cast<long long>(clock.elapsed()));
    QCOMPARE(done.count(), 1);  // no second result
    QCOMPARE(Neural(*w), before);
    QVERIFY(w->statusText().contains(QStringLiteral("cancelled")));
  }
};

}  // namespace avatar::ui

AVATAR_UI_TEST(quality, avatar::ui::QualityTest)
#include "quality_test.moc"
