#include "ui/viewport.h"

#include <QMouseEvent>
#include <QPainter>
#include <QWheelEvent>

#include <algorithm>
#include <cmath>

namespace avatar::ui {
namespace {

// Orbit speed: degrees per pixel of mouse drag.
constexpr double kDegreesPerPixel = 0.3;

}  // namespace

Viewport::Viewport(QWidget* parent) : QOpenGLWidget(parent) {
  setMinimumSize(256, 256);
  setFocusPolicy(Qt::StrongFocus);
  setToolTip(
      tr("Viewport: drop a portrait photo or a driving video here.\n"
         "Drag to orbit, wheel to zoom, double-click to reset the view."));
}

void Viewport::setImage(const QImage& image) {
  image_ = image;
  update();
}

void Viewport::setLabel(const QString& label) {
  label_ = label;
  update();
}

void Viewport::setOverlay(std::vector<QPointF> landmarks, std::vector<QPointF> vertices,
                          std::vector<cv::Vec3i> triangles) {
  landmarks_ = std::move(landmarks);
  vertices_ = std::move(vertices);
  triangles_ = std::move(triangles);
  update();
}

void Viewport::setShowLandmarks(bool show) {
  show_landmarks_ = show;
  update();
}

void Viewport::setShowMesh(bool show) {
  show_mesh_ = show;
  update();
}

QRect Viewport::imageRect() const {
  if (image_.isNull()) return {};
  // Same rule as the core's LetterboxImage so that GUI and headless views agree.
  const double scale = std::min(double(width()) / image_.width(), double(height()) / image_.height());
  const int w = std::max(1, static_cast<int>(std::lround(image_.width() * scale)));
  const int h = std::max(1, static_cast<int>(std::lround(image_.height() * scale)));
  return {(width() - w) / 2, (height() - h) / 2, w, h};
}

void Viewport::initializeGL() { initializeOpenGLFunctions(); }

void Viewport::paintGL() {
  glClearColor(0.f, 0.f, 0.f, 1.f);
  glClear(GL_COLOR_BUFFER_BIT);
  QPainter painter(this);
  if (image_.isNull()) {
    painter.setPen(QColor(160, 160, 160));
    painter.drawText(rect(), Qt::AlignCenter,
                     tr("Drop a portrait photo here\nor use File > Open (Ctrl+O)\n\n"
                        "Drop a video to drive the avatar"));
    return;
  }
  painter.setRenderHint(QPainter::SmoothPixmapTransform, true);
  const QRect target = imageRect();
  painter.drawImage(target, image_);
  const double sx = double(target.width()) / image_.width();
  const double sy = double(target.height()) / image_.height();
  auto map = [&](const QPointF& p) { return QPointF(target.x() + p.x() * sx, target.y() + p.y() * sy); };
  painter.setRenderHint(QPainter::Antialiasing, true);
  if (show_mesh_ && !triangles_.empty()) {
    painter.setPen(QPen(QColor(80, 200, 255, 110), 0.6));
    const int n = static_cast<int>(vertices_.size());
    for (const cv::Vec3i& t : triangles_) {
      if (t[0] < 0 || t[1] < 0 || t[2] < 0 || t[0] >= n || t[1] >= n || t[2] >= n) continue;
      const QPointF poly[3] = {map(vertices_[t[0]]), map(vertices_[t[1]]), map(vertices_[t[2]])};
      painter.drawPolyline(poly, 3);
    }
  }
  if (show_landmarks_) {
    painter.setPen(Qt::NoPen);
    painter.setBrush(QColor(255, 220, 40));
    for (const QPointF& p : landmarks_) painter.drawEllipse(map(p), 1.6, 1.6);
  }
  if (!label_.isEmpty()) {
    QFont f = painter.font();
    f.setBold(true);
    painter.setFont(f);
    const QRect box =
        painter.fontMetrics().boundingRect(rect().adjusted(8, 8, -8, -8), Qt::AlignLeft | Qt::TextWordWrap, label_);
    painter.fillRect(box.adjusted(-4, -2, 4, 2), QColor(0, 0, 0, 170));
    painter.setPen(QColor(255, 200, 80));
    painter.drawText(box, Qt::AlignLeft | Qt::TextWordWrap, label_);
  }
}

void Viewport::mousePressEvent(QMouseEvent* event) {
  if (event->button() == Qt::LeftButton) {
    dragging_ = true;
    last_pos_ = event->position();
  }
  QOpenGLWidget::mousePressEvent(event);
}

void Viewport::mouseMoveEvent(QMouseEvent* event) {
  if (dragging_) {
    const QPointF d = event->position() - last_pos_;
    last_pos_ = event->position();
    // Dragging right turns the head to its left (yaw > 0), dragging up tilts it up.
    if (d.x() != 0.0 || d.y() != 0.0) emit orbitDragged(d.x() * kDegreesPerPixel, -d.y() * kDegreesPerPixel);
  }
  QOpenGLWidget::mouseMoveEvent(event);
}

void Viewport::mouseReleaseEvent(QMouseEvent* event) {
  if (event->button() == Qt::LeftButton) dragging_ = false;
  QOpenGLWidget::mouseReleaseEvent(event);
}

void Viewport::wheelEvent(QWheelEvent* event) {
  const double steps = event->angleDelta().y() / 120.0;
  if (steps != 0.0) emit zoomWheeled(std::pow(1.1, steps));
  event->accept();
}

void Viewport::mouseDoubleClickEvent(QMouseEvent* event) {
  if (event->button() == Qt::LeftButton) emit resetRequested();
  QOpenGLWidget::mouseDoubleClickEvent(event);
}

}  // namespace avatar::ui
