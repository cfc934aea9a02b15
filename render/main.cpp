#include "render/render_role.hpp"

int main(int argc, char** argv) {
  return pointillist::render::runRenderMain(argc, argv);
}
