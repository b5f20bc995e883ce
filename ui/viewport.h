#pragma once
// The OpenGL viewport. Shows the latest rendered frame (the portrait, the morphable preview
// or the neural avatar: whatever the frame source renders) letterboxed on black, with a
// label saying what it is, and optional overlays of the projected landmarks and mesh. With the
// detail path it can also draw the avatar itself with OpenGL: the textured meshes of
// DetailFrameSource::ViewportMesh at a camera and face pose (showScene), which is what an orbit
// drag shows, at the speed of a redraw.
// Mouse: drag to orbit (yaw/pitch), wheel to zoom, double-click to reset the view. The
// viewport only reports these gestures; the window owns the camera state.

#include <QElapsedTimer>
#include <QImage>
#include <QPainter>
#include <QOpenGLBuffer>
#include <QOpenGLFunctions>
#include <QOpenGLShaderProgram>
#include <QOpenGLWidget>
#include <QPointF>

#include <array>
#include <memory>
#include <vector>

#include <opencv2/core.hpp>

namespace avatar {
struct HeadMesh;
}

namespace avatar::ui {

class Viewport : public QOpenGLWidget, protected QOpenGLFunctions {
  Q_OBJECT

 public:
  explicit Viewport(QWidget* parent = nullptr);
  ~Viewport() override;

  // Shows `image` fitted inside the viewport (aspect kept, black margins).
  void setImage(const QImage& image);

  // The avatar's meshes for showScene (null: none; uploaded at the next draw).
  void setScene(std::shared_ptr<const HeadMesh> scene);
  bool hasScene() const { return scene_ != nullptr; }
  // Draws the scene's meshes instead of the image, with the clip matrix of a camera
  // (render::GlClipFromWorld, column-major) whose centre is `eye` (world), over a square of the
  // image's place, the face part at `face` (its vertices at the frame's expression; empty: as
  // built). Until setImage.
  void showScene(const std::array<float, 16>& clip_from_world, const std::array<float, 3>& eye,
                 std::vector<cv::Point3f> face);
  bool showingScene() const { return showing_scene_; }
  // Scene frames drawn, and the time the last one took on the GUI thread (ms).
  quint64 sceneFramesDrawn() const { return scene_frames_; }
  double lastSceneMilliseconds() const { return last_scene_ms_; }
  // The viewport's current picture (what is on screen), for tests.
  QImage grabPicture() { return grabFramebuffer(); }
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
  // The orbit drag ended (mouse released after at least one orbitDragged).
  void orbitFinished();

 protected:
  void initializeGL() override;
  void paintGL() override;
  void mousePressEvent(QMouseEvent* event) override;
  void mouseMoveEvent(QMouseEvent* event) override;
  void mouseReleaseEvent(QMouseEvent* event) override;
  void wheelEvent(QWheelEvent* event) override;
  void mouseDoubleClickEvent(QMouseEvent* event) override;

 private:
  struct GlPart;
  void uploadScene();
  void releaseScene();  // GL context current
  void drawScene();
  QRect pictureRect() const;
  void drawLabel(QPainter& painter);

  QImage image_;
  std::shared_ptr<const HeadMesh> scene_;
  bool scene_uploaded_ = false;
  bool showing_scene_ = false;
  std::array<float, 16> clip_{};
  std::array<float, 3> eye_{};
  std::vector<cv::Point3f> face_;
  bool face_dirty_ = false;
  std::vector<std::unique_ptr<GlPart>> parts_;
  std::unique_ptr<QOpenGLShaderProgram> program_;
  quint64 scene_frames_ = 0;
  double last_scene_ms_ = 0.0;
  bool dragged_ = false;
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
