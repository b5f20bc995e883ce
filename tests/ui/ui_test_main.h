#pragma once
// The studio's Qt Test classes share one executable (test_ui): each file registers its class
// under a name with AVATAR_UI_TEST, and `test_ui NAME [Qt Test options]` runs that class alone,
// in its own process, as QTEST_MAIN would (CTest runs one process per class: ui/NAME).

#include <QObject>

#include <functional>
#include <map>
#include <memory>
#include <string>

namespace avatar::ui::testing {

using UiTestFactory = std::function<std::unique_ptr<QObject>()>;

// Name -> factory of every registered test class.
std::map<std::string, UiTestFactory>& UiTestClasses();

struct UiTestRegistration {
  UiTestRegistration(const char* name, UiTestFactory factory) { UiTestClasses()[name] = std::move(factory); }
};

}  // namespace avatar::ui::testing

#define AVATAR_UI_TEST(name, Class)                                                          \
  static const ::avatar::ui::testing::UiTestRegistration avatar_ui_test_registration_##name( \
      #name, [] { return std::unique_ptr<QObject>(new Class); });
