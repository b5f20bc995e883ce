#include "app/commands.h"

int main(int argc, char** argv) { return avatar::app::Main(argc, argv); }
