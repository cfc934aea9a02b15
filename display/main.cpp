#include "display/display_role.hpp"

int main(int argc, char** argv) {
  return pointillist::display::runDisplayMain(argc, argv);
}
