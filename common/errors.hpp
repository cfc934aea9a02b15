#pragma once
// Typed errors thrown by Pointillist libraries; each main catches them and reports
// role, rank and message.
#include <stdexcept>
#include <string>

namespace pointillist {

class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
  virtual const char* kind() const noexcept { return "error"; }
};

// Bad or damaged input files (point clouds, datasets, camera paths).
class InputError : public Error {
 public:
  using Error::Error;
  const char* kind() const noexcept override { return "input error"; }
};

// Bad command-line usage or inconsistent options.
class UsageError : public Error {
 public:
  using Error::Error;
  const char* kind() const noexcept override { return "usage error"; }
};

// A peer sent something we cannot understand, or the job layout is wrong.
class ProtocolError : public Error {
 public:
  using Error::Error;
  const char* kind() const noexcept override { return "protocol error"; }
};

// An MPI call failed; the message carries MPI_Error_string's text.
class TransportError : public Error {
 public:
  using Error::Error;
  const char* kind() const noexcept override { return "transport error"; }
};

// A wait exceeded its deadline.
class TimeoutError : public Error {
 public:
  using Error::Error;
  const char* kind() const noexcept override { return "timeout"; }
};

// A peer went silent: it stopped in the middle of a message (its payload
// never came), or the display heard nothing from it for the peer timeout.
class PeerSilentError : public TimeoutError {
 public:
  PeerSilentError(int rank, const std::string& message) : TimeoutError(message), rank_(rank) {}
  int rank() const noexcept { return rank_; }
  const char* kind() const noexcept override { return "lost process"; }

 private:
  int rank_;
};

// OpenGL / OSMesa failures.
class RenderError : public Error {
 public:
  using Error::Error;
  const char* kind() const noexcept override { return "render error"; }
};

}  // namespace pointillist
