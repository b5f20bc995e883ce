#include "ui/panels.h"

#include <QCheckBox>
#include <QComboBox>
#include <QFileInfo>
#include <QFormLayout>
#include <QGridLayout>
#include <QHBoxLayout>
#include <QLabel>
#include <QPainter>
#include <QPushButton>
#include <QSettings>
#include <QSignalBlocker>
#include <QSlider>
#include <QSpinBox>
#include <QVBoxLayout>

#include "core/pipeline/expression_preset.h"
#include "core/util/error.h"

namespace avatar::ui {
namespace {

QSlider* MakeSlider(int min, int max, int value, const QString& tooltip, QWidget* parent) {
  auto* s = new QSlider(Qt::Horizontal, parent);
  s->setRange(min, max);
  s->setValue(value);
  s->setToolTip(tooltip);
  s->setPageStep(std::max(1, (max - min) / 10));
  return s;
}

// A slider with a mnemonic label and a live value read-out, added as one form row.
void AddSliderRow(QFormLayout* form, const QString& label, QSlider* slider, const QString& unit, double scale = 1.0) {
  auto* value = new QLabel(slider->parentWidget());
  value->setMinimumWidth(44);
  value->setAlignment(Qt::AlignRight | Qt::AlignVCenter);
  auto show = [value, unit, scale](int v) {
    value->setText(QString::number(v * scale, 'f', scale < 1 ? 2 : 0) + unit);
  };
  show(slider->value());
  QObject::connect(slider, &QSlider::valueChanged, value, show);
  auto* row = new QHBoxLayout;
  row->addWidget(slider, 1);
  row->addWidget(value);
  auto* name = new QLabel(label, slider->parentWidget());
  name->setBuddy(slider);
  name->setToolTip(slider->toolTip());
  form->addRow(name, row);
}

QString PrettyName(const QString& control) {
  static const std::map<QString, QString> kNames = {
      {"jawOpen", "&Jaw open"},     {"smile", "S&mile"},          {"frown", "&Frown"},
      {"pucker", "Puc&ker"},        {"mouthWide", "Mouth &wide"}, {"browRaise", "&Brow raise"},
      {"browFrown", "Brow fr&own"}, {"blinkLeft", "Blink &left"}, {"blinkRight", "Blink ri&ght"},
      {"eyesWide", "E&yes wide"}};
  auto it = kNames.find(control);
  return it == kNames.end() ? control : it->second;
}

}  // namespace

// ---------------------------------------------------------------------------- SourcePanel

SourcePanel::SourcePanel(QWidget* parent) : QWidget(parent) {
  auto* layout = new QVBoxLayout(this);
  thumbnail_ = new QLabel(tr("No portrait\n\nFile > Open (Ctrl+O)\nor drop a photo"), this);
  thumbnail_->setAlignment(Qt::AlignCenter);
  thumbnail_->setMinimumSize(200, 200);
  thumbnail_->setFrameShape(QFrame::StyledPanel);
  thumbnail_->setToolTip(tr("The source portrait with the detected face box and landmarks"));
  layout->addWidget(thumbnail_);
  status_ = new QLabel(this);
  status_->setWordWrap(true);
  status_->setToolTip(tr("What the viewport renders for this portrait"));
  layout->addWidget(status_);

  auto* form = new QFormLayout;
  config_ = new QComboBox(this);
  config_->setObjectName(QStringLiteral("networkSize"));
  config_->addItem(tr("Lite (fast, CPU)"), "lite");
  config_->addItem(tr("Paper (slow)"), "paper");
  config_->setToolTip(tr("Network size of the random-weight plumbing check (a trained model carries its own) (Alt+W)"));
  {
    // "source/preset" is the key of 0.1; read it while the new key is not written yet.
    QSettings settings;
    const QVariant saved = settings.contains("source/config") ? settings.value("source/config")
                                                              : settings.value("source/preset", "lite");
    config_->setCurrentIndex(std::max(0, config_->findData(saved)));
  }
  auto* config_label = new QLabel(tr("Net&work size:"), this);
  config_label->setBuddy(config_);
  form->addRow(config_label, config_);
  // The quality ladder (core/pipeline/quality.h), each entry with this machine's estimates.
  quality_ = new QComboBox(this);
  quality_->setObjectName(QStringLiteral("qualityLadder"));
  quality_->setSizeAdjustPolicy(QComboBox::AdjustToContents);
  for (const QualityLevel& p : QualityLadder()) quality_->addItem(QString::fromStdString(p.name), QString::fromStdString(p.name));
  quality_->setToolTip(
      tr("Quality level: render size, samples, super-resolution and refinement steps on the photo, from instant to "
         "best (paper = the published setting). Estimates are measured on this machine at first use. (Alt+Q)"));
  quality_->setCurrentIndex(std::max(0, quality_->findData(QSettings().value("source/quality", "standard"))));
  auto* quality_label = new QLabel(tr("&Quality:"), this);
  quality_label->setBuddy(quality_);
  form->addRow(quality_label, quality_);
  layout->addLayout(form);
  setQualityEstimates(std::nullopt);
  connect(config_, &QComboBox::currentIndexChanged, this, [this] {
    QSettings().setValue("source/config", config());
    emit configChanged(config());
  });
  connect(quality_, &QComboBox::currentIndexChanged, this, [this] {
    QSettings().setValue("source/quality", quality());
    emit qualityChanged(quality());
  });

  morphable_preview_ = new QCheckBox(tr("&Morphable preview instead of the neural avatar"), this);
  morphable_preview_->setToolTip(
      tr("Shows the textured morphable-model face fitted to the portrait (fast; no hair or ears) instead of the "
         "bundled neural avatar model. (Alt+M)"));
  morphable_preview_->setChecked(QSettings().value("source/morphablePreview", false).toBool());
  connect(morphable_preview_, &QCheckBox::toggled, this,
          [](bool on) { QSettings().setValue("source/morphablePreview", on); });
  layout->addWidget(morphable_preview_);

  photo_detail_ = new QCheckBox(tr("Photo &detail on the head"), this);
  photo_detail_->setToolTip(
      tr("Warps the portrait's own pixels onto the neural head where the photo saw it (sharp, looks like "
         "the person); off shows the plain network render at once. (Alt+D)"));
  photo_detail_->setChecked(QSettings().value("source/photoDetail", true).toBool());
  connect(photo_detail_, &QCheckBox::toggled, this, [this](bool on) {
    QSettings().setValue("source/photoDetail", on);
    emit detailChanged(on);
  });
  layout->addWidget(photo_detail_);
  learned_finish_ = new QCheckBox(tr("Learned finishin&g (fusion net)"), this);
  learned_finish_->setToolTip(
      tr("Finishes each full frame of the photo's detail with the small fusion net shipped with the model "
         "(repairs what the warp did not reach; about 30 ms a frame); off shows the geometric composite. "
         "Live driving always shows the composite. (Alt+G)"));
  learned_finish_->setChecked(QSettings().value("source/learnedFinish", true).toBool());
  connect(learned_finish_, &QCheckBox::toggled, this, [this](bool on) {
    QSettings().setValue("source/learnedFinish", on);
    emit finishChanged(on);
  });
  layout->addWidget(learned_finish_);
  // The detail path goes over the neural avatar: nothing to switch under the morphable preview,
  // and the finish is the detail path's.
  const auto enable = [this] {
    photo_detail_->setEnabled(!morphable_preview_->isChecked());
    learned_finish_->setEnabled(!morphable_preview_->isChecked() && photo_detail_->isChecked());
  };
  enable();
  connect(morphable_preview_, &QCheckBox::toggled, this, enable);
  connect(photo_detail_, &QCheckBox::toggled, this, enable);

  random_weights_ = new QCheckBox(tr("Use &random network weights"), this);
  random_weights_->setToolTip(
      tr("Runs the untrained neural network with random weights: a plumbing check whose frames are NOT a "
         "result. (Alt+R)"));
  layout->addWidget(random_weights_);

  reconstruct_ = new QPushButton(tr("Reconstruct"), this);
  reconstruct_->setToolTip(tr("Analyse the portrait and build the avatar (Ctrl+R)"));
  reconstruct_->setEnabled(false);
  connect(reconstruct_, &QPushButton::clicked, this, &SourcePanel::reconstructRequested);
  layout->addWidget(reconstruct_);
  layout->addStretch(1);
}

void SourcePanel::setPortrait(const QImage& portrait, const SourceOverlay& overlay) {
  portrait_ = portrait;
  overlay_ = overlay;
  reconstruct_->setEnabled(!portrait.isNull());
  redraw();
}

void SourcePanel::redraw() {
  if (portrait_.isNull()) return;
  QImage shown = portrait_.convertToFormat(QImage::Format_RGB888);
  QPainter p(&shown);
  p.setRenderHint(QPainter::Antialiasing, true);
  const double line = std::max(1.0, shown.width() / 200.0);
  p.setPen(QPen(QColor(60, 220, 90), line * 1.5));
  for (const auto& box : overlay_.faces) p.drawRect(QRectF(box.x, box.y, box.width, box.height));
  p.setPen(Qt::NoPen);
  p.setBrush(QColor(255, 220, 40));
  for (const auto& pt : overlay_.landmarks) p.drawEllipse(QPointF(pt.x, pt.y), line, line);
  p.end();
  thumbnail_->setPixmap(QPixmap::fromImage(shown.scaled(220, 220, Qt::KeepAspectRatio, Qt::SmoothTransformation)));
}

void SourcePanel::setStatus(const QString& text) { status_->setText(text); }
QString SourcePanel::config() const { return config_->currentData().toString(); }
void SourcePanel::setConfig(const QString& config) { config_->setCurrentIndex(std::max(0, config_->findData(config))); }
QString SourcePanel::quality() const { return quality_->currentData().toString(); }
void SourcePanel::setQuality(const QString& name) { quality_->setCurrentIndex(std::max(0, quality_->findData(name))); }

void SourcePanel::setQualityEstimates(const std::optional<QualityEstimates>& estimates) {
  ModelInfo model;
  if (estimates) model.config_json = estimates->config_json;
  const auto& ladder = QualityLadder();
  for (int i = 0; i < quality_->count() && i < static_cast<int>(ladder.size()); ++i) {
    const QualityLevel& p = ladder[static_cast<size_t>(i)];
    const QualityEstimate* e = estimates ? estimates->Find(p.name) : nullptr;
    quality_->setItemText(i, QStringLiteral("%1 \u2014 %2")
                                 .arg(QString::fromStdString(p.name), QString::fromStdString(FormatQualityEstimate(e))));
    quality_->setItemData(i,
                          QString::fromStdString(p.summary + " (" + p.Describe(model) + ")"),
                          Qt::ToolTipRole);
  }
}

bool SourcePanel::randomWeights() const { return random_weights_->isChecked(); }
bool SourcePanel::morphablePreview() const { return morphable_preview_->isChecked(); }

bool SourcePanel::photoDetail() const { return photo_detail_->isChecked(); }
bool SourcePanel::learnedFinish() const { return learned_finish_->isChecked(); }

// ---------------------------------------------------------------------------- PosePanel

PosePanel::PosePanel(QWidget* parent) : QWidget(parent) {
  auto* form = new QFormLayout(this);
  yaw_ = MakeSlider(-60, 60, 0, tr("Yaw: turn the head left/right in degrees (Alt+Y, then arrow keys)"), this);
  pitch_ = MakeSlider(-40, 40, 0, tr("Pitch: tilt the head up/down in degrees (Alt+I, then arrow keys)"), this);
  roll_ = MakeSlider(-45, 45, 0, tr("Roll: rotate the head in the image plane in degrees (Alt+L)"), this);
  zoom_ = MakeSlider(50, 300, 100, tr("Zoom in percent (Alt+Z; mouse wheel in the viewport)"), this);
  AddSliderRow(form, tr("&Yaw"), yaw_, QStringLiteral("\u00b0"));
  AddSliderRow(form, tr("P&itch"), pitch_, QStringLiteral("\u00b0"));
  AddSliderRow(form, tr("Ro&ll"), roll_, QStringLiteral("\u00b0"));
  AddSliderRow(form, tr("&Zoom"), zoom_, QStringLiteral("%"));
  auto* reset = new QPushButton(tr("Reset &view"), this);
  reset->setToolTip(tr("Back to the frontal view (Ctrl+0; double-click the viewport)"));
  connect(reset, &QPushButton::clicked, this, [this] {
    setPose({});
    emit poseChanged(pose());
  });
  form->addRow(reset);
  for (QSlider* s : {yaw_, pitch_, roll_, zoom_}) {
    connect(s, &QSlider::valueChanged, this, [this] {
      if (!silent_) emit poseChanged(pose());
    });
  }
}

ViewPose PosePanel::pose() const {
  ViewPose p;
  p.yaw = yaw_->value();
  p.pitch = pitch_->value();
  p.roll = roll_->value();
  p.zoom = zoom_->value() / 100.0;
  return p;
}

void PosePanel::setPose(const ViewPose& pose) {
  // Not QSignalBlocker: the value read-outs must follow; only poseChanged is held back.
  silent_ = true;
  yaw_->setValue(static_cast<int>(std::lround(pose.yaw)));
  pitch_->setValue(static_cast<int>(std::lround(pose.pitch)));
  roll_->setValue(static_cast<int>(std::lround(pose.roll)));
  zoom_->setValue(static_cast<int>(std::lround(pose.zoom * 100.0)));
  silent_ = false;
}

// ---------------------------------------------------------------------------- ExpressionPanel

const QStringList& ExpressionPanel::ControlNames() {
  static const QStringList kNames = {"jawOpen",   "smile",     "frown",     "pucker",     "mouthWide",
                                     "browRaise", "browFrown", "blinkLeft", "blinkRight", "eyesWide"};
  return kNames;
}

ExpressionPanel::ExpressionPanel(QWidget* parent) : QWidget(parent) {
  auto* layout = new QVBoxLayout(this);
  auto* form = new QFormLayout;
  for (const QString& name : ControlNames()) {
    QSlider* s =
        MakeSlider(0, 100, 0, tr("Expression control '%1' from 0 to 1 (Alt+underlined letter)").arg(name), this);
    s->setObjectName(name);
    s->setEnabled(false);
    AddSliderRow(form, PrettyName(name), s, QString(), 0.01);
    connect(s, &QSlider::valueChanged, this, [this] {
      if (!silent_) emit expressionChanged();
    });
    sliders_[name] = s;
  }
  layout->addLayout(form);
  auto* row = new QHBoxLayout;
  auto* neutral = new QPushButton(tr("&Neutral"), this);
  neutral->setToolTip(tr("Reset every expression control to 0 (Ctrl+N)"));
  connect(neutral, &QPushButton::clicked, this, &ExpressionPanel::resetToNeutral);
  auto* save = new QPushButton(tr("&Save..."), this);
  save->setToolTip(tr("Save these expression values as an expression preset file (Ctrl+Shift+S)"));
  save->setShortcut(QKeySequence(Qt::CTRL | Qt::SHIFT | Qt::Key_S));
  connect(save, &QPushButton::clicked, this, &ExpressionPanel::saveRequested);
  auto* load = new QPushButton(tr("L&oad..."), this);
  load->setToolTip(tr("Load an expression preset file (Ctrl+Shift+L)"));
  load->setShortcut(QKeySequence(Qt::CTRL | Qt::SHIFT | Qt::Key_L));
  connect(load, &QPushButton::clicked, this, &ExpressionPanel::loadRequested);
  row->addWidget(neutral);
  row->addWidget(save);
  row->addWidget(load);
  layout->addLayout(row);
}

void ExpressionPanel::setSupported(const std::vector<std::string>& supported) {
  for (auto& [name, slider] : sliders_) {
    bool on = false;
    for (const auto& s : supported) on = on || QString::fromStdString(s) == name;
    slider->setEnabled(on);
  }
}

FrameExpression ExpressionPanel::expression() const {
  FrameExpression e;
  for (const auto& [name, slider] : sliders_) {
    if (slider->value() != 0) e.controls[name.toStdString()] = slider->value() / 100.0f;
  }
  return e;
}

void ExpressionPanel::setExpression(const FrameExpression& expression) {
  silent_ = true;  // The read-outs follow; expressionChanged is held back.
  for (auto& [name, slider] : sliders_) {
    slider->setValue(static_cast<int>(std::lround(expression.Get(name.toStdString()) * 100.0f)));
  }
  silent_ = false;
}

QSlider* ExpressionPanel::slider(const QString& name) const {
  auto it = sliders_.find(name);
  return it == sliders_.end() ? nullptr : it->second;
}

void ExpressionPanel::resetToNeutral() {
  setExpression({});
  emit expressionChanged();
}

void ExpressionPanel::savePreset(const QString& path) const {
  std::map<std::string, double> controls;
  for (const auto& [name, slider] : sliders_) controls[name.toStdString()] = slider->value() / 100.0;
  SaveExpressionPreset(path.toStdString(), controls);
}

void ExpressionPanel::loadPreset(const QString& path) {
  std::vector<std::string> known;
  for (const auto& [name, slider] : sliders_) known.push_back(name.toStdString());
  setExpression(LoadExpressionPreset(path.toStdString(), known));
  emit expressionChanged();
}

// ---------------------------------------------------------------------------- DrivingPanel

DrivingPanel::DrivingPanel(QWidget* parent) : QWidget(parent) {
  auto* grid = new QGridLayout(this);
  thumb_ = new QLabel(tr("No driver"), this);
  thumb_->setFixedSize(128, 96);
  thumb_->setAlignment(Qt::AlignCenter);
  thumb_->setFrameShape(QFrame::StyledPanel);
  thumb_->setToolTip(tr("The current frame of the driving video"));
  grid->addWidget(thumb_, 0, 0, 3, 1);

  load_ = new QPushButton(tr("Load &video..."), this);
  load_->setToolTip(tr("Load a driving video (Ctrl+Shift+O), or drop one on the window"));
  connect(load_, &QPushButton::clicked, this, &DrivingPanel::loadRequested);
  unload_ = new QPushButton(tr("&Unload"), this);
  unload_->setToolTip(tr("Stop driving: back to the sliders (Ctrl+Shift+U)"));
  unload_->setShortcut(QKeySequence(Qt::CTRL | Qt::SHIFT | Qt::Key_U));
  connect(unload_, &QPushButton::clicked, this, &DrivingPanel::unloadRequested);
  play_ = new QPushButton(tr("Play"), this);
  play_->setToolTip(tr("Play or pause the driving video (Space)"));
  connect(play_, &QPushButton::clicked, this, [this] { setPlaying(!playing_); });
  file_ = new QLabel(tr("(none)"), this);
  file_->setToolTip(tr("The loaded driving video"));
  auto* top = new QHBoxLayout;
  top->addWidget(load_);
  top->addWidget(unload_);
  top->addWidget(play_);
  top->addWidget(file_, 1);
  grid->addLayout(top, 0, 1);

  timeline_ = MakeSlider(0, 0, 0, tr("Timeline: scrub through the driving video ([ and ] step one frame)"), this);
  frame_label_ = new QLabel(QStringLiteral("0 / 0"), this);
  frame_label_->setMinimumWidth(90);
  frame_label_->setToolTip(tr("Current frame / frames in the driver"));
  auto* tl = new QHBoxLayout;
  auto* tl_label = new QLabel(tr("&Timeline"), this);
  tl_label->setBuddy(timeline_);
  tl->addWidget(tl_label);
  tl->addWidget(timeline_, 1);
  tl->addWidget(frame_label_);
  grid->addLayout(tl, 1, 1);
  connect(timeline_, &QSlider::valueChanged, this, [this](int v) {
    frame_label_->setText(QStringLiteral("%1 / %2").arg(v).arg(frames_));
    emit frameChanged(v);
  });

  auto* opts = new QHBoxLayout;
  neutral_ = new QSpinBox(this);
  neutral_->setRange(0, 0);
  neutral_->setToolTip(tr("Driver frame used as the neutral reference for relative transfer (Alt+E)"));
  auto* n_label = new QLabel(tr("N&eutral frame"), this);
  n_label->setBuddy(neutral_);
  set_neutral_ = new QPushButton(tr("Use &current"), this);
  set_neutral_->setToolTip(tr("Take the current timeline frame as the neutral reference (Ctrl+Shift+N)"));
  set_neutral_->setShortcut(QKeySequence(Qt::CTRL | Qt::SHIFT | Qt::Key_N));
  connect(set_neutral_, &QPushButton::clicked, this, [this] { neutral_->setValue(timeline_->value()); });
  mode_ = new QComboBox(this);
  mode_->addItem(tr("Relative"), true);
  mode_->addItem(tr("Absolute"), false);
  mode_->setToolTip(
      tr("Relative: apply the driver's change from its neutral frame; absolute: apply its expression "
         "as measured (Alt+A)"));
  auto* m_label = new QLabel(tr("Tr&ansfer"), this);
  m_label->setBuddy(mode_);
  smoothing_ = MakeSlider(0, 95, 30, tr("Temporal smoothing of the driver while playing (Alt+H)"), this);
  auto* s_label = new QLabel(tr("Smoot&hing"), this);
  s_label->setBuddy(smoothing_);
  follow_pose_ = new QCheckBox(tr("Follow hea&d pose"), this);
  follow_pose_->setToolTip(tr("Also turn the avatar with the driver's head (Alt+D)"));
  follow_pose_->setChecked(true);
  opts->addWidget(n_label);
  opts->addWidget(neutral_);
  opts->addWidget(set_neutral_);
  opts->addWidget(m_label);
  opts->addWidget(mode_);
  opts->addWidget(s_label);
  opts->addWidget(smoothing_, 1);
  opts->addWidget(follow_pose_);
  grid->addLayout(opts, 2, 1);
  grid->setColumnStretch(1, 1);

  QSettings settings;
  mode_->setCurrentIndex(settings.value("driving/relative", true).toBool() ? 0 : 1);
  smoothing_->setValue(settings.value("driving/smoothing", 30).toInt());
  follow_pose_->setChecked(settings.value("driving/followPose", true).toBool());
  connect(neutral_, &QSpinBox::valueChanged, this, &DrivingPanel::emitOptions);
  connect(mode_, &QComboBox::currentIndexChanged, this, &DrivingPanel::emitOptions);
  connect(smoothing_, &QSlider::valueChanged, this, &DrivingPanel::emitOptions);
  connect(follow_pose_, &QCheckBox::toggled, this, [this](bool on) {
    QSettings().setValue("driving/followPose", on);
    emit followPoseChanged(on);
  });
  clearDriver();
}

void DrivingPanel::emitOptions() {
  QSettings s;
  s.setValue("driving/relative", mode_->currentData().toBool());
  s.setValue("driving/smoothing", smoothing_->value());
  emit optionsChanged(options());
}

void DrivingPanel::setDriver(const QString& path, qint64 frames, double fps, bool measured, bool has_audio) {
  path_ = path;
  frames_ = frames;
  fps_ = fps > 0 ? fps : 25.0;
  file_->setText(tr("%1  (%2 frames, %3 fps%4)%5")
                     .arg(QFileInfo(path).fileName())
                     .arg(frames)
                     .arg(fps_, 0, 'f', 2)
                     .arg(has_audio ? tr(", audio") : QString())
                     .arg(measured ? QString() : tr(" - expressions not measured in this build")));
  {
    const QSignalBlocker a(timeline_), b(neutral_);
    timeline_->setRange(0, static_cast<int>(std::max<qint64>(0, frames - 1)));
    timeline_->setValue(0);
    neutral_->setRange(0, static_cast<int>(std::max<qint64>(0, frames - 1)));
  }
  frame_label_->setText(QStringLiteral("0 / %1").arg(frames));
  for (QWidget* w : std::initializer_list<QWidget*>{unload_, play_, timeline_, neutral_, set_neutral_, mode_,
                                                    smoothing_, follow_pose_}) {
    w->setEnabled(true);
  }
}

void DrivingPanel::clearDriver() {
  setPlaying(false);
  path_.clear();
  frames_ = 0;
  file_->setText(tr("(none: load or drop a video)"));
  thumb_->setPixmap(QPixmap());
  thumb_->setText(tr("No driver"));
  for (QWidget* w : std::initializer_list<QWidget*>{unload_, play_, timeline_, neutral_, set_neutral_, mode_,
                                                    smoothing_, follow_pose_}) {
    w->setEnabled(false);
  }
}

int DrivingPanel::currentFrame() const { return timeline_->value(); }
void DrivingPanel::setCurrentFrame(int frame) { timeline_->setValue(frame); }

void DrivingPanel::setPlaying(bool playing) {
  if (playing && frames_ <= 0) playing = false;
  if (playing == playing_) return;
  playing_ = playing;
  play_->setText(playing ? tr("Pause") : tr("Play"));
  emit playingChanged(playing);
}

DrivingOptions DrivingPanel::options() const {
  DrivingOptions o;
  o.relative = mode_->currentData().toBool();
  o.neutral_frame = neutral_->value();
  o.smoothing = smoothing_->value() / 100.0;
  return o;
}

void DrivingPanel::setOptions(const DrivingOptions& options) {
  const QSignalBlocker a(mode_), b(neutral_), c(smoothing_);
  mode_->setCurrentIndex(options.relative ? 0 : 1);
  neutral_->setValue(static_cast<int>(options.neutral_frame));
  smoothing_->setValue(static_cast<int>(std::lround(options.smoothing * 100)));
}

bool DrivingPanel::followPose() const { return follow_pose_->isChecked(); }

void DrivingPanel::setDriverImage(const QImage& frame, bool face_found) {
  if (frame.isNull()) return;
  QImage shown = frame.scaled(thumb_->size(), Qt::KeepAspectRatio, Qt::SmoothTransformation);
  if (!face_found) {
    QPainter p(&shown);
    p.setPen(QColor(255, 80, 80));
    p.drawText(shown.rect(), Qt::AlignBottom | Qt::AlignHCenter, tr("no face"));
  }
  thumb_->setPixmap(QPixmap::fromImage(shown));
}

}  // namespace avatar::ui
