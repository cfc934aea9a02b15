#pragma once
// Role counts of an MPMD job: display, traverse, data-send, render.
#include <cstdint>
#include <string>

namespace pointillist {

struct JobLayout {
  std::uint32_t display = 1;
  std::uint32_t traverse = 2;
  std::uint32_t datasend = 1;
  std::uint32_t render = 4;

  std::uint32_t total() const { return display + traverse + datasend + render; }
  std::string toString() const;  // "1,2,1,4"
  // Parses "D,T,S,R"; throws UsageError naming the text when it is malformed
  // or when a role that must exist has a zero count.
  static JobLayout parse(const std::string& text);
  // Throws ProtocolError unless there is one display and at least one of each other role.
  void validate() const;

  bool operator==(const JobLayout&) const = default;
};

}  // namespace pointillist
