#include "common/tool_entry.hpp"

#include <cstdio>
#include <exception>

#include "common/errors.hpp"

namespace pointillist {

int runToolMain(const char* tool, const std::function<int()>& body) {
  try {
    return body();
  } catch (const Error& error) {
    std::fprintf(stderr, "%s: %s: %s\n", tool, error.kind(), error.what());
  } catch (const std::exception& error) {
    std::fprintf(stderr, "%s: unexpected error: %s\n", tool, error.what());
  }
  return 2;
}

}  // namespace pointillist
