// LibTorch headers (through the pipeline) first: Qt's `slots` keyword macro breaks them when it is defined earlier.
#include "core/pipeline/head_mesh.h"

#include "ui/viewport.h"

#include <QMouseEvent>
#include <QPainter>
#include <QSurfaceFormat>
#include <QWheelEvent>

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>


namespace avatar::ui {
namespace {

// Orbit speed: degrees per pixel of mouse drag.
constexpr double kDegreesPerPixel = 0.3;

// The scene's shaders: GLSL 1.10, which every desktop context this widget gets (Mesa's
// llvmpipe included) compiles. Texture coordinates have their origin at the texture's first row,
// as the meshes' uv and the uploaded rows do.
const char* kSceneVertexShader = R"(
attribute vec3 position;
attribute vec2 uv;
uniform mat4 clip;
uniform vec3 eye;
uniform float push;
varying vec2 v_uv;
void main() {
  v_uv = uv;
  // push > 1 moves a vertex away from the eye along its own ray: the same pixel, a farther depth.
  gl_Position = clip * vec4(eye + (position - eye) * push, 1.0);
}
)";
const char* kSceneFragmentShader = R"(
uniform sampler2D tex;
varying vec2 v_uv;
void main() {
  gl_FragColor = vec4(texture2D(tex, v_uv).rgb, 1.0);
}
)";

// Floats per vertex: x, y, z, u, v.
constexpr int kVertexFloats = 5;
// The head's height field continues under the face mesh; drawn this much farther along each ray
// (3% of the distance, about 8 cm at the default framing), the face mesh wins wherever both are.
// The network's backdrops ("network ..." parts) go farther still, one step each, so the photo's
// parts win over them and they do not flicker against each other.
constexpr float kHeadPush = 1.03f;
constexpr float kBackdropPush = 1.06f;
constexpr float kBackdropStep = 0.01f;

}  // namespace

struct Viewport::GlPart {
  QOpenGLBuffer vertices{QOpenGLBuffer::VertexBuffer};
  QOpenGLBuffer indices{QOpenGLBuffer::IndexBuffer};
  GLuint texture = 0;
  int index_count = 0;
  bool is_face = false;
  float push = 1.0f;
  std::vector<float> interleaved;  // the face's, rewritten when its vertices change
};

Viewport::Viewport(QWidget* parent) : QOpenGLWidget(parent) {
  QSurfaceFormat format = this->format();
  format.setDepthBufferSize(24);
  setFormat(format);
  setMinimumSize(256, 256);
  setFocusPolicy(Qt::StrongFocus);
  setToolTip(
      tr("Viewport: drop a portrait photo or a driving video here.\n"
         "Drag to orbit, wheel to zoom, double-click to reset the view."));
}

Viewport::~Viewport() {
  if (!parts_.empty() || program_) {
    makeCurrent();
    releaseScene();
    program_.reset();
    doneCurrent();
  }
}

void Viewport::setImage(const QImage& image) {
  image_ = image;
  showing_scene_ = false;
  update();
}

void Viewport::setScene(std::shared_ptr<const HeadMesh> scene) {
  scene_ = std::move(scene);
  scene_uploaded_ = false;
  if (!scene_) showing_scene_ = false;
  update();
}

void Viewport::showScene(const std::array<float, 16>& clip_from_world, const std::array<float, 3>& eye,
                         std::vector<cv::Point3f> face) {
  if (!scene_) return;
  clip_ = clip_from_world;
  eye_ = eye;
  if (!face.empty()) {
    face_ = std::move(face);
    face_dirty_ = true;
  }
  showing_scene_ = true;
  update();
}

void Viewport::releaseScene() {
  for (auto& part : parts_) {
    part->vertices.destroy();
    part->indices.destroy();
    if (part->texture != 0) glDeleteTextures(1, &part->texture);
  }
  parts_.clear();
}

void Viewport::uploadScene() {
  releaseScene();
  scene_uploaded_ = true;
  face_dirty_ = !face_.empty();
  if (!scene_) return;
  if (!program_) {
    program_ = std::make_unique<QOpenGLShaderProgram>();
    if (!program_->addShaderFromSourceCode(QOpenGLShader::Vertex, kSceneVertexShader) ||
        !program_->addShaderFromSourceCode(QOpenGLShader::Fragment, kSceneFragmentShader) || !program_->link()) {
      qWarning("Viewport: the scene's shaders do not build here (%s); showing rendered frames only",
               qPrintable(program_->log()));
      program_.reset();
      scene_.reset();
      showing_scene_ = false;
      return;
    }
  }
  int backdrops = 0;
  for (const TexturedMesh& mesh : scene_->parts) {
    if (mesh.triangles.empty() || mesh.positions.empty() || mesh.texture.empty()) continue;
    auto part = std::make_unique<GlPart>();
    part->is_face = mesh.name == "face";
    if (mesh.name.rfind("network", 0) == 0) {
      part->push = kBackdropPush + kBackdropStep * static_cast<float>(backdrops++);
    } else {
      part->push = part->is_face ? 1.0f : kHeadPush;
    }
    part->interleaved.resize(mesh.positions.size() * kVertexFloats);
    for (size_t i = 0; i < mesh.positions.size(); ++i) {
      float* v = &part->interleaved[i * kVertexFloats];
      v[0] = mesh.positions[i].x;
      v[1] = mesh.positions[i].y;
      v[2] = mesh.positions[i].z;
      v[3] = mesh.uv[i].x;
      v[4] = mesh.uv[i].y;
    }
    part->vertices.create();
    part->vertices.setUsagePattern(part->is_face ? QOpenGLBuffer::DynamicDraw : QOpenGLBuffer::StaticDraw);
    part->vertices.bind();
    part->vertices.allocate(part->interleaved.data(), static_cast<int>(part->interleaved.size() * sizeof(float)));
    part->vertices.release();
    std::vector<GLuint> indices;
    indices.reserve(mesh.triangles.size() * 3);
    for (const cv::Vec3i& t : mesh.triangles)
      for (int k = 0; k < 3; ++k) indices.push_back(static_cast<GLuint>(t[k]));
    part->index_count = static_cast<int>(indices.size());
    part->indices.create();
    part->indices.bind();
    part->indices.allocate(indices.data(), static_cast<int>(indices.size() * sizeof(GLuint)));
    part->indices.release();
    cv::Mat rgb;
    if (mesh.texture.channels() == 4) {
      cv::cvtColor(mesh.texture, rgb, cv::COLOR_BGRA2RGB);
    } else {
      cv::cvtColor(mesh.texture, rgb, cv::COLOR_BGR2RGB);
    }
    if (!rgb.isContinuous()) rgb = rgb.clone();
    glGenTextures(1, &part->texture);
    glBindTexture(GL_TEXTURE_2D, part->texture);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGB, rgb.cols, rgb.rows, 0, GL_RGB, GL_UNSIGNED_BYTE, rgb.data);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    glBindTexture(GL_TEXTURE_2D, 0);
    parts_.push_back(std::move(part));
  }
}

QRect Viewport::pictureRect() const {
  if (!image_.isNull()) return imageRect();
  const int side = std::max(1, std::min(width(), height()));
  return {(width() - side) / 2, (height() - side) / 2, side, side};
}

void Viewport::drawScene() {
  QElapsedTimer timer;
  timer.start();
  if (!scene_uploaded_) uploadScene();
  if (!program_ || parts_.empty()) return;
  if (face_dirty_) {
    for (auto& part : parts_) {
      if (!part->is_face || face_.size() * kVertexFloats != part->interleaved.size()) continue;
      for (size_t i = 0; i < face_.size(); ++i) {
        float* v = &part->interleaved[i * kVertexFloats];
        v[0] = face_[i].x;
        v[1] = face_[i].y;
        v[2] = face_[i].z;
      }
      part->vertices.bind();
      part->vertices.write(0, part->interleaved.data(), static_cast<int>(part->interleaved.size() * sizeof(float)));
      part->vertices.release();
    }
    face_dirty_ = false;
  }
  const QRect r = pictureRect();
  const qreal dpr = devicePixelRatioF();
  glViewport(static_cast<GLint>(std::lround(r.x() * dpr)),
             static_cast<GLint>(std::lround((height() - r.y() - r.height()) * dpr)),
             static_cast<GLsizei>(std::lround(r.width() * dpr)), static_cast<GLsizei>(std::lround(r.height() * dpr)));
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LESS);
  glDisable(GL_CULL_FACE);
  glDisable(GL_BLEND);
  program_->bind();
  glUniformMatrix4fv(program_->uniformLocation("clip"), 1, GL_FALSE, clip_.data());
  program_->setUniformValue("tex", 0);
  program_->setUniformValue("eye", eye_[0], eye_[1], eye_[2]);
  const int position = program_->attributeLocation("position");
  const int uv = program_->attributeLocation("uv");
  glActiveTexture(GL_TEXTURE0);
  for (auto& part : parts_) {
    part->vertices.bind();
    program_->enableAttributeArray(position);
    program_->setAttributeBuffer(position, GL_FLOAT, 0, 3, kVertexFloats * sizeof(float));
    program_->enableAttributeArray(uv);
    program_->setAttributeBuffer(uv, GL_FLOAT, 3 * sizeof(float), 2, kVertexFloats * sizeof(float));
    program_->setUniformValue("push", part->push);
    glBindTexture(GL_TEXTURE_2D, part->texture);
    part->indices.bind();
    glDrawElements(GL_TRIANGLES, part->index_count, GL_UNSIGNED_INT, nullptr);
    part->indices.release();
    part->vertices.release();
  }
  program_->disableAttributeArray(position);
  program_->disableAttributeArray(uv);
  glBindTexture(GL_TEXTURE_2D, 0);
  program_->release();
  glDisable(GL_DEPTH_TEST);
  glViewport(0, 0, static_cast<GLsizei>(std::lround(width() * dpr)), static_cast<GLsizei>(std::lround(height() * dpr)));
  ++scene_frames_;
  last_scene_ms_ = static_cast<double>(timer.nsecsElapsed()) / 1e6;
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
  glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
  if (showing_scene_ && scene_) {
    drawScene();
    // The label only: the overlays belong to the last rendered frame, not to this view.
    QPainter painter(this);
    drawLabel(painter);
    return;
  }
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
  drawLabel(painter);
}

void Viewport::drawLabel(QPainter& painter) {
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
    if (d.x() != 0.0 || d.y() != 0.0) {
      dragged_ = true;
      emit orbitDragged(d.x() * kDegreesPerPixel, -d.y() * kDegreesPerPixel);
    }
  }
  QOpenGLWidget::mouseMoveEvent(event);
}

void Viewport::mouseReleaseEvent(QMouseEvent* event) {
  if (event->button() == Qt::LeftButton) {
    dragging_ = false;
    if (dragged_) {
      dragged_ = false;
      emit orbitFinished();
    }
  }
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
