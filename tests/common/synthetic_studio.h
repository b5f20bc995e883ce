#pragma once
// Set-up shared by the GUI tests (tests/ui) that run the real analysis/fit/render path.
// LibTorch (via the morphable model) first: Qt's `slots` macro breaks its headers.
#include "morphable/morphable_test_util.h"

#include <QByteArray>
#include <QCoreApplication>
#include <QSettings>
#include <QStandardPaths>
#include <QString>
#include <QTemporaryDir>

#include "ui/studio.h"

namespace avatar::ui::testing {

// Saves a synthetic morphable model (smooth random bases on the installed topology) in `dir`
// and points the studio at it, so tests drive the real path without depending on the committed
// model; then switches QSettings to a test-mode store cleared of earlier runs. Returns an error
// message, empty on success.
inline QString UseSyntheticModelAndTestSettings(const QTemporaryDir& dir) {
  if (!dir.isValid()) return QStringLiteral("no temporary folder for the synthetic model");
  const std::string model = dir.filePath(QStringLiteral("synthetic.avmm")).toStdString();
  morphable::testing::SyntheticModel(morphable::testing::InstalledTopology(), 6, 12).Save(model);
  qputenv("AVATAR_MORPHABLE_MODEL", QByteArray::fromStdString(model));
  QStandardPaths::setTestModeEnabled(true);
  SetApplicationIdentity();
  QCoreApplication::setOrganizationName(QStringLiteral("AvatarStudioTest"));
  QSettings().clear();
  return {};
}

}  // namespace avatar::ui::testing
