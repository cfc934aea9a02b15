#include "display/service_frame_source.hpp"

#include <csignal>

namespace pointillist::display {
namespace {

volatile std::sig_atomic_t stopSignal = 0;

extern "C" void onStopSignal(int signal) {
  stopSignal = signal;
}

}  // namespace

ServiceFrameSource::ServiceFrameSource(service::ServiceOptions options,
                                       service::ServedDataset dataset)
    : frontEnd_(
          std::make_unique<service::ServiceFrontEnd>(std::move(options), std::move(dataset))) {
  // A clean stop: the frames out are finished and every process is shut down.
  struct sigaction action {};
  action.sa_handler = onStopSignal;
  sigemptyset(&action.sa_mask);
  sigaction(SIGINT, &action, nullptr);
  sigaction(SIGTERM, &action, nullptr);
}

ServiceFrameSource::~ServiceFrameSource() {
  close();
}

std::vector<FrameRequest> ServiceFrameSource::take(std::size_t room) {
  std::vector<FrameRequest> frames;
  while (frames.size() < room) {
    auto order = frontEnd_->nextFrame();
    if (!order) break;
    frames.push_back({order->camera, order->settings});
    orders_.push_back(std::move(*order));
  }
  return frames;
}

bool ServiceFrameSource::finished() {
  if (stopSignal != 0 && !frontEnd_->shutdownRequested()) {
    frontEnd_->requestShutdown(stopSignal == SIGINT ? "SIGINT" : "SIGTERM");
  }
  return frontEnd_->shutdownRequested();
}

void ServiceFrameSource::frameDone(const FinishedFrame& frame, Image image) {
  if (orders_.empty()) {
    throw ProtocolError("display: frame " + std::to_string(frame.record.frame) +
                        " finished, but no client asked for it");
  }
  service::FrameOrder order = std::move(orders_.front());
  orders_.pop_front();
  service::FrameOutcome outcome;
  outcome.frameId = frame.record.frame;
  outcome.splats = frame.record.splats;
  outcome.tiles = frame.record.tiles;
  outcome.bytesOrdered = frame.record.bytesOrdered;
  outcome.incomplete = !frame.failedTiles.empty();
  frontEnd_->frameDone(std::move(order), outcome, std::move(image));
}

std::string ServiceFrameSource::stopReason() const {
  return frontEnd_->shutdownReason();
}

void ServiceFrameSource::close() {
  if (frontEnd_) frontEnd_->close();
}

}  // namespace pointillist::display
