#include "ui/viewport.h"

#include <QPainter>

#include <algorithm>
#include <cmath>

namespace avatar::ui {

Viewport::Viewport(QWidget* parent) : QOpenGLWidget(parent) {
  setMinimumSize(256, 256);
  setToolTip(tr("Viewport: drop a portrait photo here"));
}

void Viewport::setImage(const QImage& image) {
  image_ = image;
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
  if (image_.isNull()) {
    QPainter painter(this);
    painter.setPen(QColor(160, 160, 160));
    painter.drawText(rect(), Qt::AlignCenter, tr("Drop a portrait photo here\nor use File > Open (Ctrl+O)"));
    return;
  }
  QPainter painter(this);
  painter.setRenderHint(QPainter::SmoothPixmapTransform, true);
  painter.drawImage(imageRect(), image_);
}

}  // namespace avatar::ui
