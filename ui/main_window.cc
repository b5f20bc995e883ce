#include "ui/main_window.h"

#include <QAction>
#include <QApplication>
#include <QCloseEvent>
#include <QDragEnterEvent>
#include <QDropEvent>
#include <QFileDialog>
#include <QFileInfo>
#include <QLabel>
#include <QMenu>
#include <QMenuBar>
#include <QMessageBox>
#include <QMimeData>
#include <QSettings>
#include <QStatusBar>

#include "core/io/image_io.h"
#include "core/util/error.h"
#include "core/util/version.h"
#include "ui/image_convert.h"
#include "ui/viewport.h"

namespace avatar::ui {
namespace {

constexpr int kMaxRecentFiles = 8;
const char* const kRecentKey = "recentFiles";
const char* const kGeometryKey = "mainWindow/geometry";
const char* const kStateKey = "mainWindow/state";

QString LocalFileFromMime(const QMimeData* mime) {
  if (mime == nullptr || !mime->hasUrls()) return {};
  for (const QUrl& url : mime->urls()) {
    if (url.isLocalFile() && IsImageFile(url.toLocalFile())) return url.toLocalFile();
  }
  return {};
}

}  // namespace

bool IsImageFile(const QString& path) {
  static const QStringList kExtensions = {"jpg", "jpeg", "png", "bmp", "tif", "tiff", "webp"};
  return kExtensions.contains(QFileInfo(path).suffix().toLower());
}

MainWindow::MainWindow(QWidget* parent) : QMainWindow(parent) {
  setWindowTitle(QStringLiteral("Avatar Studio"));
  setAcceptDrops(true);
  viewport_ = new Viewport(this);
  setCentralWidget(viewport_);
  status_label_ = new QLabel(tr("No portrait loaded"), this);
  statusBar()->addWidget(status_label_, 1);
  createMenus();

  QSettings settings;
  if (!restoreGeometry(settings.value(kGeometryKey).toByteArray())) resize(1280, 720);
  restoreState(settings.value(kStateKey).toByteArray());
}

MainWindow::~MainWindow() = default;

void MainWindow::createMenus() {
  QMenu* file = menuBar()->addMenu(tr("&File"));
  QAction* open = file->addAction(tr("&Open Portrait..."), this, &MainWindow::showOpenDialog);
  open->setShortcut(QKeySequence::Open);
  open->setToolTip(tr("Open a portrait photo (JPEG, PNG, ...)"));
  recent_menu_ = file->addMenu(tr("Open &Recent"));
  rebuildRecentMenu();
  file->addSeparator();
  QAction* quit = file->addAction(tr("&Quit"), this, &QWidget::close);
  quit->setShortcut(QKeySequence::Quit);

  QMenu* help = menuBar()->addMenu(tr("&Help"));
  help->addAction(tr("&About Avatar Studio"), this, &MainWindow::showAbout);
}

bool MainWindow::openPortrait(const QString& path) {
  try {
    const cv::Mat bgr = LoadImageBgr(path.toStdString());
    viewport_->setImage(ToQImage(bgr));
    last_error_.clear();
    status_label_->setText(tr("%1  (%2 x %3)").arg(QFileInfo(path).fileName()).arg(bgr.cols).arg(bgr.rows));
    setWindowTitle(tr("%1 - Avatar Studio").arg(QFileInfo(path).fileName()));
    addRecentFile(QFileInfo(path).absoluteFilePath());
    emit portraitLoaded(path);
    return true;
  } catch (const std::exception& e) {
    last_error_ = QString::fromStdString(e.what());
    status_label_->setText(tr("Could not open %1").arg(QFileInfo(path).fileName()));
    if (dialogs_enabled_) QMessageBox::warning(this, tr("Could not open the portrait"), last_error_);
    emit portraitFailed(path, last_error_);
    return false;
  }
}

void MainWindow::dragEnterEvent(QDragEnterEvent* event) {
  if (!LocalFileFromMime(event->mimeData()).isEmpty()) event->acceptProposedAction();
}

void MainWindow::dropEvent(QDropEvent* event) {
  const QString path = LocalFileFromMime(event->mimeData());
  if (path.isEmpty()) return;
  event->acceptProposedAction();
  openPortrait(path);
}

void MainWindow::closeEvent(QCloseEvent* event) {
  QSettings settings;
  settings.setValue(kGeometryKey, saveGeometry());
  settings.setValue(kStateKey, saveState());
  QMainWindow::closeEvent(event);
}

QStringList MainWindow::recentFiles() const { return QSettings().value(kRecentKey).toStringList(); }

void MainWindow::addRecentFile(const QString& path) {
  QStringList files = recentFiles();
  files.removeAll(path);
  files.prepend(path);
  while (files.size() > kMaxRecentFiles) files.removeLast();
  QSettings().setValue(kRecentKey, files);
  rebuildRecentMenu();
}

void MainWindow::rebuildRecentMenu() {
  recent_menu_->clear();
  const QStringList files = recentFiles();
  for (const QString& f : files) {
    recent_menu_->addAction(QFileInfo(f).fileName(), this, [this, f] { openPortrait(f); })->setToolTip(f);
  }
  recent_menu_->setEnabled(!files.isEmpty());
}

void MainWindow::showOpenDialog() {
  const QString path = QFileDialog::getOpenFileName(this, tr("Open Portrait"), QString(),
                                                    tr("Images (*.jpg *.jpeg *.png *.bmp *.tif *.tiff *.webp)"));
  if (!path.isEmpty()) openPortrait(path);
}

void MainWindow::showAbout() {
  QMessageBox::about(this, tr("About Avatar Studio"),
                     tr("<b>Avatar Studio %1</b><p>Turns one portrait photo into an animatable 3D head avatar "
                        "(Generalizable One-shot Neural Head Avatar, NeurIPS 2023).</p>")
                         .arg(QString::fromLatin1(kVersion)));
}

}  // namespace avatar::ui
