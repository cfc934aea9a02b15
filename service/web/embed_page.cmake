# cmake -DINPUT=viewer.html -DOUTPUT=viewer_page.cpp -P embed_page.cmake
# Writes the page as a raw string literal behind viewerPage().
file(READ "${INPUT}" _page)
set(_delimiter "pointillist_page")
string(FIND "${_page}" ")${_delimiter}" _clash)
if(NOT _clash EQUAL -1)
  message(FATAL_ERROR "${INPUT} contains the raw-string delimiter )${_delimiter}")
endif()
file(WRITE "${OUTPUT}.part" "// Generated from ${INPUT} by embed_page.cmake; do not edit.
#include \"service/web/viewer_page.hpp\"

namespace pointillist::service::web {

std::string_view viewerPage() {
  static constexpr std::string_view page = R\"${_delimiter}(${_page})${_delimiter}\";
  return page;
}

}  // namespace pointillist::service::web
")
file(RENAME "${OUTPUT}.part" "${OUTPUT}")
