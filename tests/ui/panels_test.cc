// The panels and the export dialog: expression presets round-trip and refuse bad files with
// the file's name, the driving options map to the core's, the dialog's choices become the
// core's export plan and are remembered; the network size is named "Network size" (config) and
// its setting falls back to the 0.1 key.
#include <QAbstractButton>
#include <QComboBox>
#include <QLabel>
#include <QRegularExpression>
#include <QSettings>
#include <QSignalSpy>
#include <QSlider>
#include <QStandardPaths>
#include <QTemporaryDir>
#include <QtTest/QtTest>

#include "ui_test_main.h"

#include "common/test_settings.h"
#include "core/util/error.h"
#include "ui/export_dialog.h"
#include "ui/panels.h"
#include "ui/studio.h"

namespace avatar::ui {

class PanelsTest : public QObject {
  Q_OBJECT

 private slots:
  void initTestCase() {
    testing::UsePrivateTestSettings(QStringLiteral("AvatarStudioPanelsTest"));
  }

  void expressionPresetsRoundTrip() {
    QTemporaryDir dir;
    ExpressionPanel panel;
    panel.setSupported({"smile", "jawOpen"});
    QVERIFY(panel.slider("smile")->isEnabled());
    QVERIFY(!panel.slider("pucker")->isEnabled());
    panel.slider("smile")->setValue(40);
    panel.slider("jawOpen")->setValue(75);
    QCOMPARE(panel.expression().Get("smile"), 0.40f);
    const QString file = dir.filePath(QStringLiteral("happy.json"));
    panel.savePreset(file);
    QSignalSpy changed(&panel, &ExpressionPanel::expressionChanged);
    panel.resetToNeutral();
    QVERIFY(panel.expression().controls.empty());
    panel.loadPreset(file);
    QCOMPARE(panel.expression().Get("smile"), 0.40f);
    QCOMPARE(panel.expression().Get("jawOpen"), 0.75f);
    QCOMPARE(changed.count(), 2);  // Neutral, then load.
  }

  void badPresetsAreRefusedWithTheFileName() {
    QTemporaryDir dir;
    ExpressionPanel panel;
    panel.slider("smile")->setValue(10);
    const QString broken = dir.filePath(QStringLiteral("broken.json"));
    const QString unknown = dir.filePath(QStringLiteral("unknown.json"));
    {
      QFile f(broken);
      QVERIFY(f.open(QIODevice::WriteOnly));
      f.write("{ not json");
    }
    {
      QFile f(unknown);
      QVERIFY(f.open(QIODevice::WriteOnly));
      f.write("{\"expression\": {\"wink\": 1}}");
    }
    for (const QString& path : {broken, unknown, dir.filePath(QStringLiteral("missing.json"))}) {
      try {
        panel.loadPreset(path);
        QFAIL(qPrintable(path + " was accepted"));
      } catch (const Error& e) {
        QVERIFY2(QString::fromStdString(e.what()).contains(QFileInfo(path).fileName()), e.what());
      }
    }
    QCOMPARE(panel.expression().Get("smile"), 0.10f);  // Unchanged by the failed loads.
  }

  void drivingOptionsMapToTheCore() {
    DrivingPanel panel;
    QVERIFY(!panel.hasDriver());
    panel.setDriver(QStringLiteral("/x/clip.mp4"), 100, 25.0, true, false);
    QVERIFY(panel.hasDriver());
    QCOMPARE(panel.timeline()->maximum(), 99);
    DrivingOptions o;
    o.relative = false;
    o.neutral_frame = 42;
    o.smoothing = 0.6;
    panel.setOptions(o);
    const DrivingOptions back = panel.options();
    QCOMPARE(back.relative, false);
    QCOMPARE(back.neutral_frame, int64_t{42});
    QCOMPARE(back.smoothing, 0.6);
    QSignalSpy frames(&panel, &DrivingPanel::frameChanged);
    panel.setCurrentFrame(10);
    QCOMPARE(frames.count(), 1);
    panel.clearDriver();
    QVERIFY(!panel.timeline()->isEnabled());
  }

  void exportDialogBuildsThePlanAndRemembersIt() {
    {
      ExportDialog dialog(true, QStringLiteral("lite"));
      dialog.setOutput(QStringLiteral("/tmp/frames_out"));
      dialog.setViewMode(QStringLiteral("orbit"));
      dialog.setSquareSize(256);
      dialog.setMaxFrames(10);
      const AnimationPlan plan = dialog.plan();
      QCOMPARE(QString::fromStdString(plan.view.mode), QStringLiteral("orbit"));
      QCOMPARE(plan.width, 256);
      QCOMPARE(plan.max_frames, int64_t{10});
      QCOMPARE(QString::fromStdString(dialog.exportOptions().ResolvedFormat()), QStringLiteral("png"));
      dialog.saveSettings();
    }
    ExportDialog again(false, QStringLiteral("lite"));
    QCOMPARE(QString::fromStdString(again.exportOptions().output), QStringLiteral("/tmp/frames_out"));
    QCOMPARE(QString::fromStdString(again.plan().view.mode), QStringLiteral("orbit"));
    QCOMPARE(again.plan().width, 256);
  }

  // Issue 31 (one word per idea): the network size is "Network size" / config, persisted as
  // "source/config"; the 0.1 key "source/preset" is read while the new one is absent.
  void networkSizeIsNamedConfigAndReadsTheOldSettingsKey() {
    QSettings().remove(QStringLiteral("source/config"));
    QSettings().setValue(QStringLiteral("source/preset"), QStringLiteral("paper"));
    {
      SourcePanel panel;
      QCOMPARE(panel.config(), QStringLiteral("paper"));
      QSignalSpy changed(&panel, &SourcePanel::configChanged);
      panel.setConfig(QStringLiteral("lite"));
      QCOMPARE(changed.count(), 1);
      QCOMPARE(changed.at(0).at(0).toString(), QStringLiteral("lite"));
      QCOMPARE(QSettings().value(QStringLiteral("source/config")).toString(), QStringLiteral("lite"));
      QCOMPARE(panel.configBox()->objectName(), QStringLiteral("networkSize"));
      bool labelled = false;
      for (const QLabel* label : panel.findChildren<QLabel*>()) {
        if (label->buddy() == panel.configBox()) labelled = label->text().remove('&') == QStringLiteral("Network size:");
      }
      QVERIFY(labelled);
    }
    SourcePanel again;  // The new key wins over the old one.
    QCOMPARE(again.config(), QStringLiteral("lite"));
    QSettings().remove(QStringLiteral("source/config"));
    QSettings().remove(QStringLiteral("source/preset"));
    SourcePanel fresh;  // Neither key: the default.
    QCOMPARE(fresh.config(), QStringLiteral("lite"));

    ExportDialog dialog(false, QStringLiteral("paper"));
    const auto* shown = dialog.findChild<QLabel*>(QStringLiteral("networkSizeLabel"));
    QVERIFY(shown != nullptr);
    QCOMPARE(shown->text(), QStringLiteral("Network size: paper"));

    // "preset" is left to expression presets in the widgets' texts and tooltips.
    const QRegularExpression preset(QStringLiteral("preset"), QRegularExpression::CaseInsensitiveOption);
    for (QWidget* root : std::initializer_list<QWidget*>{&fresh, &dialog}) {
      for (const QWidget* w : root->findChildren<QWidget*>()) {
        QString text = w->toolTip();
        if (const auto* label = qobject_cast<const QLabel*>(w)) text += " " + label->text();
        if (const auto* button = qobject_cast<const QAbstractButton*>(w)) text += " " + button->text();
        if (const auto* box = qobject_cast<const QComboBox*>(w)) {
          for (int i = 0; i < box->count(); ++i) text += " " + box->itemText(i);
        }
        QVERIFY2(!text.contains(preset), qPrintable(w->objectName() + ": " + text));
      }
    }
  }
};

}  // namespace avatar::ui

AVATAR_UI_TEST(panels, avatar::ui::PanelsTest)
#include "panels_test.moc"
