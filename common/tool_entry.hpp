#pragma once
// Entry point of the standalone (non-MPI) tools: runs body and turns an
// exception into "tool: kind: message" on stderr and exit code 2.
#include <functional>

namespace pointillist {

int runToolMain(const char* tool, const std::function<int()>& body);

}  // namespace pointillist
