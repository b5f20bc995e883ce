#pragma once
// The OpenGL viewport. At this stage it shows the loaded portrait centred on black; later
// it shows the rendered avatar.

#include <QImage>
#include <QOpenGLFunctions>
#include <QOpenGLWidget>

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

  QSize sizeHint() const override { return {800, 800}; }

 protected:
  void initializeGL() override;
  void paintGL() override;

 private:
  QImage image_;
};

}  // namespace avatar::ui
