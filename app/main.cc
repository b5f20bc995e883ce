#include "app/commands.h"
#include "core/util/threads.h"

int main(int argc, char** argv) {
  avatar::ReexecWithPassiveOpenMpWait(argv);
  return avatar::app::Main(argc, argv);
}
