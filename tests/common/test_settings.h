#pragma once
// Settings of the studio's tests (tests/ui): private to one test process.
#include <QCoreApplication>
#include <QSettings>
#include <QStandardPaths>
#include <QString>
#include <QTemporaryDir>

#include "ui/studio.h"

namespace avatar::ui::testing {

// Names the application as the studio does, with `organization`, and gives this process a
// settings store of its own, empty. QStandardPaths' test mode alone moves the store to
// ~/.qttest, which every test process shares: under `ctest -j2` ui/studio turned the morphable
// preview on while ui/quality, beside it, read that setting and reconstructed a morphable
// preview where it expected the neural avatar. The store lives in a temporary folder removed
// when the process ends. Call before the first QSettings is made.
inline void UsePrivateTestSettings(const QString& organization) {
  static QTemporaryDir store;
  QStandardPaths::setTestModeEnabled(true);
  SetApplicationIdentity();
  QCoreApplication::setOrganizationName(organization);
  if (store.isValid()) {
    QSettings::setPath(QSettings::NativeFormat, QSettings::UserScope, store.path());
    QSettings::setPath(QSettings::IniFormat, QSettings::UserScope, store.path());
  }
  QSettings().clear();
}

}  // namespace avatar::ui::testing
