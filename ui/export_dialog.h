#pragma once
// The export dialog: where to, MP4 or PNG+alpha, which camera (driver's pose, source pose,
// turntable orbit), resolution, length and audio. It only collects choices; the window runs
// the export through the shared core (core/pipeline/animate.h) on its job worker.

#include <QDialog>

#include "core/pipeline/animate.h"
#include "core/pipeline/export.h"

class QCheckBox;
class QComboBox;
class QDoubleSpinBox;
class QLineEdit;
class QSpinBox;

namespace avatar::ui {

class ExportDialog : public QDialog {
  Q_OBJECT

 public:
  // `has_driver`: a driving video or keyframes are loaded (enables "driver's pose" and audio);
  // `config`: the network size chosen in the source panel (shown).
  ExportDialog(bool has_driver, const QString& config, QWidget* parent = nullptr);

  // The choices (after exec() returned Accepted). The plan's expression is left empty.
  ExportOptions exportOptions() const;
  AnimationPlan plan() const;

  // For tests and scripted use.
  void setOutput(const QString& path);
  void setMaxFrames(int frames);
  void setViewMode(const QString& mode);  // driver, source or orbit.
  void setSquareSize(int pixels);

  // Remembers the choices in QSettings (called on accept).
  void saveSettings() const;

 private:
  void browse();
  void updateEnabled();
  void acceptIfValid();

  bool has_driver_;
  QLineEdit* output_ = nullptr;
  QComboBox* format_ = nullptr;
  QComboBox* view_ = nullptr;
  QDoubleSpinBox* orbit_ = nullptr;
  QComboBox* size_ = nullptr;
  QSpinBox* max_frames_ = nullptr;
  QDoubleSpinBox* seconds_ = nullptr;
  QDoubleSpinBox* fps_ = nullptr;
  QCheckBox* audio_ = nullptr;
};

}  // namespace avatar::ui
