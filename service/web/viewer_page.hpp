#pragma once
// The viewer page (service/web/viewer.html), built into the binary by CMake.
#include <string_view>

namespace pointillist::service::web {

std::string_view viewerPage();

}  // namespace pointillist::service::web
