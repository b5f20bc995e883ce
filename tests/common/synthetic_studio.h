#pragma once
// Set-up shared by the GUI tests (tests/ui) that run the real analysis/fit/render path.
// LibTorch (via the morphable model) first: Qt's `slots` macro breaks its headers.
#include "morphable/morphable_test_util.h"

#include <QByteArray>
#include <QString>
#include <QTemporaryDir>

#include "common/test_settings.h"

namespace avatar::ui::testing {

// Saves a synthetic morphable model (smooth random bases on the installed topology) in `dir`
// and points the studio at it, so tests drive the real path without depending on the committed
// model; then gives the process an empty settings store of its own. Returns an error
// message, empty on success.
inline QString UseSyntheticModelAndTestSettings(const QTemporaryDir& dir) {
  if (!dir.isValid()) return QStringLiteral("no temporary folder for the synthetic model");
  const std::string model = dir.filePath(QStringLiteral("synthetic.avmm")).toStdString();
  morphable::testing::SyntheticModel(morphable::testing::InstalledTopology(), 6, 12).Save(model);
  qputenv("AVATAR_MORPHABLE_MODEL", QByteArray::fromStdString(model));
  UsePrivateTestSettings(QStringLiteral("AvatarStudioTest"));
  return {};
}

}  // namespace avatar::ui::testing
