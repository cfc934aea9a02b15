#pragma once
// Serve mode's frame source: frames clients ask for over ZeroMQ, composed
// frames handed back to the service for encoding and sending. SIGINT and
// SIGTERM end it like a shutdown request.
#include <deque>
#include <memory>
#include <string>

#include "display/frame_source.hpp"
#include "service/zmq/service_front_end.hpp"

namespace pointillist::display {

class ServiceFrameSource final : public FrameSource {
 public:
  ServiceFrameSource(service::ServiceOptions options, service::ServedDataset dataset);
  ~ServiceFrameSource() override;

  std::vector<FrameRequest> take(std::size_t room) override;
  bool finished() override;
  void frameDone(const FinishedFrame& frame, Image image) override;

  const service::ServiceFrontEnd& frontEnd() const { return *frontEnd_; }
  std::string stopReason() const;
  // Sends what is encoded and closes the sockets.
  void close();

 private:
  std::unique_ptr<service::ServiceFrontEnd> frontEnd_;
  std::deque<service::FrameOrder> orders_;  // started frames, oldest first
};

}  // namespace pointillist::display
