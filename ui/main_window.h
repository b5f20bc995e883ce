#pragma once
// The studio's main window: menus, the viewport, a status bar, drag and drop of portraits,
// recent files and window geometry kept in QSettings.

#include <QMainWindow>
#include <QStringList>

class QMenu;
class QLabel;

namespace avatar::ui {

class Viewport;

class MainWindow : public QMainWindow {
  Q_OBJECT

 public:
  explicit MainWindow(QWidget* parent = nullptr);
  ~MainWindow() override;

  // Loads a portrait through the core's image loader and shows it. This is the single path
  // used by File > Open, recent files, drag and drop and the --open flag. On failure the
  // error is shown (a dialog when dialogs are enabled, always in the status bar) and false
  // is returned.
  bool openPortrait(const QString& path);

  // Dialogs are on by default; tests switch them off so nothing blocks.
  void setDialogsEnabled(bool enabled) { dialogs_enabled_ = enabled; }

  Viewport* viewport() const { return viewport_; }
  QStringList recentFiles() const;
  // The message of the last failed open ("" after a success).
  QString lastError() const { return last_error_; }

 signals:
  void portraitLoaded(const QString& path);
  void portraitFailed(const QString& path, const QString& message);

 protected:
  void dragEnterEvent(QDragEnterEvent* event) override;
  void dropEvent(QDropEvent* event) override;
  void closeEvent(QCloseEvent* event) override;

 private:
  void createMenus();
  void rebuildRecentMenu();
  void addRecentFile(const QString& path);
  void showOpenDialog();
  void showAbout();

  Viewport* viewport_ = nullptr;
  QMenu* recent_menu_ = nullptr;
  QLabel* status_label_ = nullptr;
  QString last_error_;
  bool dialogs_enabled_ = true;
};

// True if the file name looks like an image the studio opens (by extension).
bool IsImageFile(const QString& path);

}  // namespace avatar::ui
