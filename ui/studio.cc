#include "ui/studio.h"

#include <QApplication>
#include <QTimer>

#include "core/util/version.h"
#include "ui/main_window.h"

namespace avatar::ui {

void SetApplicationIdentity() {
  QCoreApplication::setOrganizationName(QStringLiteral("AvatarStudio"));
  QCoreApplication::setApplicationName(QStringLiteral("avatar-studio"));
  QCoreApplication::setApplicationVersion(QString::fromLatin1(kVersion));
}

int RunStudio(int& argc, char** argv, const StudioOptions& options) {
  QApplication app(argc, argv);
  SetApplicationIdentity();
  QGuiApplication::setDesktopFileName(QStringLiteral("avatar-studio"));
  MainWindow window;
  window.show();
  if (!options.open.empty()) {
    const QString path = QString::fromStdString(options.open);
    QTimer::singleShot(0, &window, [&window, path] { window.openPortrait(path); });
  }
  if (!options.driver.empty()) {
    const QString path = QString::fromStdString(options.driver);
    QTimer::singleShot(0, &window, [&window, path] { window.openDriver(path); });
  }
  return app.exec();
}

}  // namespace avatar::ui
