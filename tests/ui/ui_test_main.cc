// main() of test_ui: runs the one Qt Test class named by the first argument (ui_test_main.h).
#include "ui_test_main.h"

#include <QApplication>
#include <QtTest/QtTest>

#include <cstdio>
#include <vector>

namespace avatar::ui::testing {

std::map<std::string, UiTestFactory>& UiTestClasses() {
  static std::map<std::string, UiTestFactory> classes;
  return classes;
}

}  // namespace avatar::ui::testing

int main(int argc, char** argv) {
  const auto& classes = avatar::ui::testing::UiTestClasses();
  if (argc < 2 || classes.count(argv[1]) == 0) {
    std::fprintf(stderr, "usage: %s CLASS [Qt Test options]\nCLASS is one of:", argv[0]);
    for (const auto& [name, factory] : classes) std::fprintf(stderr, " %s", name.c_str());
    std::fprintf(stderr, "\n");
    return 2;
  }
  const std::string name = argv[1];
  // The remaining arguments, as the class's own executable would have seen them.
  std::vector<char*> args{argv[0]};
  for (int i = 2; i < argc; ++i) args.push_back(argv[i]);
  int n = static_cast<int>(args.size());
  args.push_back(nullptr);
  // As QTEST_MAIN does for a widgets test.
  QApplication app(n, args.data());
  app.setAttribute(Qt::AA_Use96Dpi, true);
  std::unique_ptr<QObject> test = classes.at(name)();
  return QTest::qExec(test.get(), n, args.data());
}
