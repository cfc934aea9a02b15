#include "traverse/traverse_role.hpp"

int main(int argc, char** argv) {
  return pointillist::runRoleMain(argc, argv, pointillist::v1::ROLE_TRAVERSE,
                                  pointillist::traverse::runTraverseRole);
}
