#pragma once
// The side panels of the studio window: source, pose, expression and driving. Each panel
// only holds widgets and reports user changes with signals; the window owns the state and
// the workers.

#include <QImage>
#include <QString>
#include <QStringList>
#include <QWidget>

#include <map>
#include <optional>
#include <vector>

#include "core/pipeline/driving.h"
#include "core/pipeline/frame_source.h"
#include "core/pipeline/quality.h"

class QCheckBox;
class QComboBox;
class QLabel;
class QPushButton;
class QSlider;
class QSpinBox;

namespace avatar::ui {

// Portrait thumbnail with the detection/landmark overlay, network size and quality level
// choices and Reconstruct.
class SourcePanel : public QWidget {
  Q_OBJECT

 public:
  explicit SourcePanel(QWidget* parent = nullptr);
  // Shows `portrait` with the overlay (detections and landmarks in portrait pixels).
  void setPortrait(const QImage& portrait, const SourceOverlay& overlay);
  void setStatus(const QString& text);
  // The network size (model config) of the random-weight network: "lite" or "paper" (persisted as
  // "source/config"; settings of 0.1 kept it as "source/preset", read when the new key is absent).
  QString config() const;
  void setConfig(const QString& config);
  QComboBox* configBox() const { return config_; }
  // The quality level chosen in the ladder (a QualityLadder() name; persisted).
  QString quality() const;
  void setQuality(const QString& name);
  // Shows each level's estimated reconstruct and frame time beside its name ("not measured
  // yet" for nullopt).
  void setQualityEstimates(const std::optional<QualityEstimates>& estimates);
  QComboBox* qualityBox() const { return quality_; }
  bool randomWeights() const;
  // The user chose the morphable preview instead of the neural avatar.
  bool morphablePreview() const;
  QPushButton* reconstructButton() const { return reconstruct_; }
  QCheckBox* randomWeightsBox() const { return random_weights_; }
  QCheckBox* morphablePreviewBox() const { return morphable_preview_; }
  // The photo's own detail over the neural head (BackendOptions::detail "head"), else "off".
  bool photoDetail() const;
  QCheckBox* photoDetailBox() const { return photo_detail_; }
  // The photo's detail finished by the bundled fusion net (BackendOptions::detail "head"), else
  // the geometric composite ("geometric"); only with photoDetail().
  bool learnedFinish() const;
  QCheckBox* learnedFinishBox() const { return learned_finish_; }

 signals:
  void reconstructRequested();
  void configChanged(const QString& config);
  void qualityChanged(const QString& quality);
  void detailChanged(bool on);
  void finishChanged(bool learned);

 private:
  void redraw();
  QLabel* thumbnail_ = nullptr;
  QLabel* status_ = nullptr;
  QComboBox* config_ = nullptr;
  QComboBox* quality_ = nullptr;
  QCheckBox* random_weights_ = nullptr;
  QCheckBox* morphable_preview_ = nullptr;
  QCheckBox* photo_detail_ = nullptr;
  QCheckBox* learned_finish_ = nullptr;
  QPushButton* reconstruct_ = nullptr;
  QImage portrait_;
  SourceOverlay overlay_;
};

// Yaw, pitch, roll and zoom.
class PosePanel : public QWidget {
  Q_OBJECT

 public:
  explicit PosePanel(QWidget* parent = nullptr);
  ViewPose pose() const;
  // Sets the sliders without emitting poseChanged.
  void setPose(const ViewPose& pose);
  QSlider* yawSlider() const { return yaw_; }
  QSlider* pitchSlider() const { return pitch_; }
  QSlider* rollSlider() const { return roll_; }
  QSlider* zoomSlider() const { return zoom_; }

 signals:
  void poseChanged(const avatar::ViewPose& pose);

 private:
  QSlider* yaw_ = nullptr;
  QSlider* pitch_ = nullptr;
  QSlider* roll_ = nullptr;
  QSlider* zoom_ = nullptr;
  bool silent_ = false;  // setPose() in progress.
};

// One slider per named expression control, Neutral, and expression presets.
class ExpressionPanel : public QWidget {
  Q_OBJECT

 public:
  explicit ExpressionPanel(QWidget* parent = nullptr);
  // Enables the sliders of `supported` (the others stay visible but disabled).
  void setSupported(const std::vector<std::string>& supported);
  FrameExpression expression() const;
  // Sets the sliders (names not in the panel are ignored) without emitting.
  void setExpression(const FrameExpression& expression);
  QSlider* slider(const QString& name) const;

  // Presets: JSON {"expression": {"smile": 0.5, ...}}, read and written by
  // core/pipeline/expression_preset.h (only this panel's controls are accepted). Throw Io / InvalidInput.
  void savePreset(const QString& path) const;
  void loadPreset(const QString& path);

  // The controls shown, in order (the morphable model's named controls).
  static const QStringList& ControlNames();

 signals:
  void expressionChanged();
  void saveRequested();
  void loadRequested();

 public slots:
  void resetToNeutral();

 private:
  std::map<QString, QSlider*> sliders_;
  bool silent_ = false;  // setExpression() in progress.
};

// Driving video: load, play/pause, timeline, neutral frame, transfer mode, smoothing.
class DrivingPanel : public QWidget {
  Q_OBJECT

 public:
  explicit DrivingPanel(QWidget* parent = nullptr);
  // Called when the worker opened a driver.
  void setDriver(const QString& path, qint64 frames, double fps, bool measured, bool has_audio);
  void clearDriver();
  bool hasDriver() const { return frames_ > 0; }
  QString driverPath() const { return path_; }
  double fps() const { return fps_; }
  qint64 frameCount() const { return frames_; }

  int currentFrame() const;
  void setCurrentFrame(int frame);  // Emits frameChanged.
  bool isPlaying() const { return playing_; }
  void setPlaying(bool playing);
  DrivingOptions options() const;
  void setOptions(const DrivingOptions& options);
  bool followPose() const;
  void setDriverImage(const QImage& frame, bool face_found);

  QSlider* timeline() const { return timeline_; }
  QPushButton* playButton() const { return play_; }

 signals:
  void loadRequested();
  void unloadRequested();
  void frameChanged(int frame);
  void playingChanged(bool playing);
  void optionsChanged(const avatar::DrivingOptions& options);
  void followPoseChanged(bool follow);

 private:
  void emitOptions();
  QString path_;
  qint64 frames_ = 0;
  double fps_ = 25.0;
  bool playing_ = false;
  QLabel* file_ = nullptr;
  QLabel* thumb_ = nullptr;
  QLabel* frame_label_ = nullptr;
  QPushButton* load_ = nullptr;
  QPushButton* unload_ = nullptr;
  QPushButton* play_ = nullptr;
  QPushButton* set_neutral_ = nullptr;
  QSlider* timeline_ = nullptr;
  QSpinBox* neutral_ = nullptr;
  QComboBox* mode_ = nullptr;
  QSlider* smoothing_ = nullptr;
  QCheckBox* follow_pose_ = nullptr;
};

}  // namespace avatar::ui
