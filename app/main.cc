// avatar-studio: every command lives in the avatar_app library (app/commands.h); main only
// dispatches, to a command or, in GUI builds, to the studio.
#include "app/commands.h"
#include "core/util/threads.h"

int main(int argc, char** argv) {
  avatar::ReexecWithPassiveOpenMpWait(argv);
#ifdef AVATAR_WITH_GUI
  return avatar::app::Main(argc, argv, &avatar::app::RunGui);
#else
  return avatar::app::Main(argc, argv, nullptr);
#endif
}
