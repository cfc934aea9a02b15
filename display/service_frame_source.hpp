#pragma once
// Serve mode's frame source: frames clients ask for over ZeroMQ, composed
// frames handed back to the service for encoding and sending. SIGINT and
// SIGTERM end it like a shutdown request.
//
// With the render cache on (interimMs >= 0), each client that sends single
// cameras (render requests: a person moving the view) has a RenderCache fed
// with its final frames and their depth. A new camera is reprojected from it
// at once: the interim frame goes to the client when the final one is not
// composed interimMs after the frame started, and its priority image orders
// the frame's tiles (the regions the cache could not fill are drawn first).
// Final frames go into the caches on a thread of their own, after they went
// to the client: the display goes on receiving tiles and starting frames
// meanwhile, and a reprojection may run during an insert.
#include <chrono>
#include <deque>
#include <map>
#include <memory>
#include <string>

#include "display/core/render_cache.hpp"
#include "display/frame_source.hpp"
#include "service/zmq/service_front_end.hpp"

namespace pointillist::display {

struct RenderCacheServing {
  double interimMs = -1.0;  // negative: no render cache
  RenderCacheOptions cache;
  std::size_t maxClients = 8;  // caches kept; the least recently used goes
  // Reproject before the frame's tiles go out and order them by the cache's
  // priority; false: reproject at the next poll, the tiles in the
  // scheduler's order.
  bool tilePriority = true;
  // After the interim frame went out, the tiles that arrived since go too
  // (the region they cover), at most this often (0: every turn with new
  // tiles), until the final frame; negative: one interim frame only.
  double refreshMs = -1.0;
};

class ServiceFrameSource final : public FrameSource {
 public:
  ServiceFrameSource(service::ServiceOptions options, service::ServedDataset dataset,
                     RenderCacheServing renderCache = {});
  ~ServiceFrameSource() override;

  std::vector<FrameRequest> take(std::size_t room) override;
  bool finished() override;
  void frameDone(const FinishedFrame& frame, Image image, std::vector<float> depth) override;
  void tileComposed(const ComposedTile& tile, const Image& composed) override;
  void poll() override;

  const service::ServiceFrontEnd& frontEnd() const { return *frontEnd_; }
  std::string stopReason() const;
  // Sends what is encoded and closes the sockets.
  void close();
  // Render cache figures over the run, for the display's summary.
  std::string renderCacheSummary() const;

 private:
  struct ClientCache {
    ClientCache(const RenderCacheOptions& options, v1::RenderMode cachedMode)
        : cache(options), mode(cachedMode) {}
    RenderCache cache;
    v1::RenderMode mode = v1::RENDER_MODE_UNSPECIFIED;  // the frames it holds
    std::chrono::steady_clock::time_point used;
  };
  struct Started {
    service::FrameOrder order;
    std::uint64_t frame = 0;
    std::shared_ptr<const InterimFrame> interim;  // none: no cache for it
    bool reprojectPending = false;                // --tile-priority none: at the next poll
    std::chrono::steady_clock::time_point due;
    bool interimSent = false;
    // The interim image with the tiles composed so far pasted in (made at
    // the first tile); what the client sees until the final frame.
    Image shown;
    std::uint32_t tilesShown = 0, tilesSent = 0, tiles = 0;
    // The bounding box of the tiles pasted since the last interim frame went
    // (empty: x1 <= x0): a refresh sends only that region.
    std::uint32_t changedX0 = 0, changedY0 = 0, changedX1 = 0, changedY1 = 0;
    std::chrono::steady_clock::time_point lastSent;
  };
  ClientCache* cacheFor(const std::string& clientId, v1::RenderMode mode);
  // The client's cache if it holds frames of `order`'s mode; none otherwise.
  ClientCache* cacheHolding(const service::FrameOrder& order);
  std::shared_ptr<const InterimFrame> reproject(ClientCache& client, const Camera& camera);
  // A `--tile-priority none` frame's reprojection, when it is still to run.
  void reprojectIfPending(Started& started);
  void sendInterim(Started& started, std::chrono::steady_clock::time_point now);
  class Inserter;

  std::unique_ptr<service::ServiceFrontEnd> frontEnd_;
  v1::RunSettings run_;
  RenderCacheServing renderCache_;
  std::map<std::string, ClientCache> caches_;
  // After caches_: its jobs point into them, so it stops first.
  std::unique_ptr<Inserter> inserter_;
  std::deque<Started> started_;  // oldest first
  std::uint64_t nextFrame_ = 0;
  std::uint64_t interimsMade_ = 0, interimsSent_ = 0, refreshesSent_ = 0;
  double reprojectSeconds_ = 0.0, filledSum_ = 0.0;
};

}  // namespace pointillist::display
