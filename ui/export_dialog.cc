#include "ui/export_dialog.h"

#include <QCheckBox>
#include <QComboBox>
#include <QDialogButtonBox>
#include <QDir>
#include <QDoubleSpinBox>
#include <QFileDialog>
#include <QFileInfo>
#include <QFormLayout>
#include <QHBoxLayout>
#include <QLabel>
#include <QLineEdit>
#include <QMessageBox>
#include <QPushButton>
#include <QSettings>
#include <QSpinBox>

namespace avatar::ui {

ExportDialog::ExportDialog(bool has_driver, const QString& config, QWidget* parent)
    : QDialog(parent), has_driver_(has_driver) {
  setWindowTitle(tr("Export Animation"));
  QSettings settings;
  auto* form = new QFormLayout;

  output_ = new QLineEdit(settings.value("export/output", QDir::home().filePath("avatar.mp4")).toString(), this);
  output_->setToolTip(tr("Output file (.mp4) or a folder for the PNG sequence"));
  auto* browse = new QPushButton(tr("&Browse..."), this);
  browse->setToolTip(tr("Choose where to write the export"));
  connect(browse, &QPushButton::clicked, this, &ExportDialog::browse);
  auto* out_row = new QHBoxLayout;
  out_row->addWidget(output_, 1);
  out_row->addWidget(browse);
  form->addRow(tr("&Output:"), out_row);

  format_ = new QComboBox(this);
  format_->addItem(tr("MP4 video (H.264, driver's audio kept)"), "mp4");
  format_->addItem(tr("PNG sequence with alpha"), "png");
  format_->setCurrentIndex(format_->findData(settings.value("export/format", "mp4")));
  format_->setToolTip(tr("MP4 for sharing; PNG frames keep the head's true opacity for compositing"));
  form->addRow(tr("&Format:"), format_);

  view_ = new QComboBox(this);
  view_->addItem(tr("Driver's head pose"), "driver");
  view_->addItem(tr("Source pose (fixed camera)"), "source");
  view_->addItem(tr("Orbit (turntable)"), "orbit");
  view_->setToolTip(tr("Which camera the export uses"));
  const int saved_view = view_->findData(settings.value("export/view", has_driver ? "driver" : "orbit"));
  view_->setCurrentIndex(saved_view < 0 ? 0 : saved_view);
  form->addRow(tr("&Camera:"), view_);

  orbit_ = new QDoubleSpinBox(this);
  orbit_->setRange(0, 90);
  orbit_->setSuffix(QStringLiteral(" deg"));
  orbit_->setValue(settings.value("export/orbit", 30.0).toDouble());
  orbit_->setToolTip(tr("Turntable: the camera sweeps this many degrees to each side"));
  form->addRow(tr("Orbit &sweep:"), orbit_);

  size_ = new QComboBox(this);
  for (int s : {256, 384, 512, 768, 1024}) size_->addItem(QStringLiteral("%1 x %1").arg(s), s);
  size_->setCurrentIndex(std::max(0, size_->findData(settings.value("export/size", 512))));
  size_->setToolTip(tr("Output resolution in pixels"));
  form->addRow(tr("&Resolution:"), size_);

  max_frames_ = new QSpinBox(this);
  max_frames_->setRange(0, 1000000);
  max_frames_->setSpecialValueText(tr("all"));
  max_frames_->setValue(0);
  max_frames_->setToolTip(tr("Stop after this many frames (all = the whole driver)"));
  form->addRow(tr("&Frames:"), max_frames_);

  seconds_ = new QDoubleSpinBox(this);
  seconds_->setRange(0.2, 600);
  seconds_->setSuffix(QStringLiteral(" s"));
  seconds_->setValue(settings.value("export/seconds", 4.0).toDouble());
  seconds_->setToolTip(tr("Length of the clip when there is no driver"));
  form->addRow(tr("&Length:"), seconds_);

  fps_ = new QDoubleSpinBox(this);
  fps_->setRange(1, 120);
  fps_->setValue(settings.value("export/fps", 25.0).toDouble());
  fps_->setToolTip(tr("Frames per second when there is no driving video (a video keeps its own rate)"));
  form->addRow(tr("Frame &rate:"), fps_);

  audio_ = new QCheckBox(tr("Keep the driver's &audio"), this);
  audio_->setChecked(settings.value("export/audio", true).toBool());
  audio_->setToolTip(tr("Copy the driving video's sound track into the MP4"));
  form->addRow(QString(), audio_);

  auto* config_label = new QLabel(tr("Network size: %1").arg(config), this);
  config_label->setObjectName(QStringLiteral("networkSizeLabel"));
  config_label->setToolTip(tr("The network size chosen in the source panel"));
  form->addRow(QString(), config_label);

  auto* buttons = new QDialogButtonBox(QDialogButtonBox::Ok | QDialogButtonBox::Cancel, this);
  buttons->button(QDialogButtonBox::Ok)->setText(tr("&Export"));
  buttons->button(QDialogButtonBox::Ok)->setToolTip(tr("Start the export (it runs in the background; Esc cancels)"));
  connect(buttons, &QDialogButtonBox::accepted, this, &ExportDialog::acceptIfValid);
  connect(buttons, &QDialogButtonBox::rejected, this, &QDialog::reject);
  auto* layout = new QVBoxLayout(this);
  layout->addLayout(form);
  layout->addWidget(buttons);

  connect(format_, &QComboBox::currentIndexChanged, this, &ExportDialog::updateEnabled);
  connect(view_, &QComboBox::currentIndexChanged, this, &ExportDialog::updateEnabled);
  updateEnabled();
}

void ExportDialog::updateEnabled() {
  const bool mp4 = format_->currentData().toString() == "mp4";
  audio_->setEnabled(mp4 && has_driver_);
  orbit_->setEnabled(view_->currentData().toString() == "orbit");
  seconds_->setEnabled(!has_driver_);
  fps_->setEnabled(!has_driver_);
}

void ExportDialog::browse() {
  const bool mp4 = format_->currentData().toString() == "mp4";
  const QString path = mp4 ? QFileDialog::getSaveFileName(this, tr("Export MP4"), output_->text(), tr("MP4 (*.mp4)"))
                           : QFileDialog::getExistingDirectory(this, tr("Folder for the PNG frames"),
                                                               QFileInfo(output_->text()).absolutePath());
  if (!path.isEmpty()) output_->setText(path);
}

void ExportDialog::acceptIfValid() {
  try {
    exportOptions().Validate();
    plan().view.Validate();
  } catch (const std::exception& e) {
    QMessageBox::warning(this, tr("Cannot export"), QString::fromStdString(e.what()));
    return;
  }
  saveSettings();
  accept();
}

ExportOptions ExportDialog::exportOptions() const {
  ExportOptions o;
  o.output = output_->text().trimmed().toStdString();
  o.format = format_->currentData().toString().toStdString();
  o.fps = fps_->value();
  return o;
}

AnimationPlan ExportDialog::plan() const {
  AnimationPlan p;
  p.view.mode = view_->currentData().toString().toStdString();
  p.view.orbit_degrees = orbit_->value();
  p.width = p.height = size_->currentData().toInt();
  p.fps = fps_->value();
  p.seconds = seconds_->value();
  p.max_frames = max_frames_->value();
  p.keep_audio = audio_->isChecked();
  return p;
}

void ExportDialog::setOutput(const QString& path) {
  output_->setText(path);
  format_->setCurrentIndex(format_->findData(path.endsWith(".mp4", Qt::CaseInsensitive) ? "mp4" : "png"));
}
void ExportDialog::setMaxFrames(int frames) { max_frames_->setValue(frames); }
void ExportDialog::setViewMode(const QString& mode) { view_->setCurrentIndex(std::max(0, view_->findData(mode))); }
void ExportDialog::setSquareSize(int pixels) { size_->setCurrentIndex(std::max(0, size_->findData(pixels))); }

void ExportDialog::saveSettings() const {
  QSettings s;
  s.setValue("export/output", output_->text());
  s.setValue("export/format", format_->currentData());
  s.setValue("export/view", view_->currentData());
  s.setValue("export/orbit", orbit_->value());
  s.setValue("export/size", size_->currentData());
  s.setValue("export/seconds", seconds_->value());
  s.setValue("export/fps", fps_->value());
  s.setValue("export/audio", audio_->isChecked());
}

}  // namespace avatar::ui
