#include "datasend/datasend_role.hpp"

int main(int argc, char** argv) {
  return pointillist::datasend::runDatasendMain(argc, argv);
}
