#pragma once
// The OpenGL viewport. Shows the latest rendered frame (the portrait, the morphable preview
// or the neural avatar: whatever the frame source renders) letterboxed on black, with a
// label saying what it is, and optional overlays of the projected landmarks and mesh.
// Mouse: drag to orbit (yaw/pitch), wheel to zoom, double-click to reset the view. The
// viewport only reports these gestures; the window owns the camera state.

#include <QImage>
#include <QOpenGLFunctions>
#include <QOpenGLWidget>
#include <QPointF>

#include <vector>

#include <opencv2/core.hpp>

namespace avatar::ui {

class Viewport : public QOpenGLWidget, protected QOpenGLFunctions {
  Q_OBJECT

 public:
  explicit Viewport(QWidget* parent = nullptr);

  // Shows `image` fitted inside the viewport (aspect kept, black margins).
  void setImage(const QImage& image);
  const QImage& image() const { return image_; }
  // Where the image is drawn, in widget coordinates (empty when there is no image).
  QRect imageRect() const;

  // Text drawn in the top-left corner (what the frame is, e.g. "Preview: morphable model").
  void setLabel(const QString& label);
  QString label() const { return label_; }
  // Overlays in image pixel coordinates; drawn when enabled.
  void setOverlay(std::vector<QPointF> landmarks, std::vector<QPointF> vertices, std::vector<cv::Vec3i> triangles);
  void setShowLandmarks(bool show);
  void setShowMesh(bool show);
  bool showLandmarks() const { return show_landmarks_; }
  bool showMesh() const { return show_mesh_; }

  QSize sizeHint() const override { return {720, 640}; }

 signals:
  // Drag: degrees of yaw and pitch to add.
  void orbitDragged(double yaw_degrees, double pitch_degrees);
  // Wheel: multiply the zoom by `factor`.
  void zoomWheeled(double factor);
  // Double-click: back to the default view.
  void resetRequested();

 protected:
  void initializeGL() override;
  void paintGL() override;
  void mousePressEvent(QMouseEvent* event) override;
  void mouseMoveEvent(QMouseEvent* event) override;
  void mouseReleaseEvent(QMouseEvent* event) override;
  void wheelEvent(QWheelEvent* event) override;
  void mouseDoubleClickEvent(QMouseEvent* event) override;

 private:
  QImage image_;
  QString label_;
  std::vector<QPointF> landmarks_;
  std::vector<QPointF> vertices_;
  std::vector<cv::Vec3i> triangles_;
  bool show_landmarks_ = false;
  bool show_mesh_ = false;
  bool dragging_ = false;
  QPointF last_pos_;
};

}  // namespace avatar::ui
