#include "traverse/traverse_role.hpp"

int main(int argc, char** argv) {
  return pointillist::traverse::runTraverseMain(argc, argv);
}
