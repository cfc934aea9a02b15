#include "common/job_layout.hpp"

#include <charconv>
#include <vector>

#include "common/errors.hpp"

namespace pointillist {

std::string JobLayout::toString() const {
  return std::to_string(display) + "," + std::to_string(traverse) + "," + std::to_string(datasend) +
         "," + std::to_string(render);
}

JobLayout JobLayout::parse(const std::string& text) {
  std::vector<std::uint32_t> counts;
  std::size_t start = 0;
  while (start <= text.size()) {
    const std::size_t comma = text.find(',', start);
    const std::size_t end = comma == std::string::npos ? text.size() : comma;
    std::uint32_t value = 0;
    const char* first = text.data() + start;
    const char* last = text.data() + end;
    const auto [ptr, ec] = std::from_chars(first, last, value);
    if (first == last || ec != std::errc() || ptr != last || value > 4096) {
      throw UsageError("layout '" + text +
                       "' is not D,T,S,R (four counts: display, traverse, data-send, render)");
    }
    counts.push_back(value);
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  if (counts.size() != 4) {
    throw UsageError("layout '" + text + "' has " + std::to_string(counts.size()) +
                     " counts; expected four: display,traverse,data-send,render");
  }
  JobLayout layout{counts[0], counts[1], counts[2], counts[3]};
  try {
    layout.validate();
  } catch (const ProtocolError& error) {
    throw UsageError(std::string("layout '") + text + "': " + error.what());
  }
  return layout;
}

void JobLayout::validate() const {
  if (display != 1) {
    throw ProtocolError("a job needs exactly one display process, found " +
                        std::to_string(display));
  }
  if (traverse == 0 || datasend == 0 || render == 0) {
    throw ProtocolError(
        "a job needs at least one traverse, one data-send and one render process (layout " +
        toString() + ")");
  }
}

}  // namespace pointillist
