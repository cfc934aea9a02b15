#include "render/render_role.hpp"

#include <chrono>
#include <cmath>
#include <limits>
#include <map>
#include <memory>
#include <thread>

#include "common/checksum.hpp"
#include "common/cpu_activity.hpp"
#include "common/dataset.hpp"
#include "common/image.hpp"
#include "common/image_compression.hpp"
#include "common/mpi/worker.hpp"
#include "common/ownership.hpp"
#include "common/pixel_runs.hpp"
#include "common/point_groups.hpp"
#include "common/run_settings.hpp"
#include "common/shared_packets.hpp"
#include "render/core/render_core.hpp"
#include "render/gl/tile_renderers.hpp"
#include "render/raster/cpu_point_renderer.hpp"

namespace pointillist::render {
namespace {

// Whether the tile is cleared to the colour the display composes on.
bool clearIsFrameBackground(const RenderSettings& settings) {
  for (std::size_t c = 0; c < 4; ++c) {
    const float channel = settings.clearColor[c];
    if (!(channel >= 0.0f && channel <= 1.0f) ||
        static_cast<std::uint8_t>(std::lround(channel * 255.0f)) != kFrameBackground[c])
      return false;
  }
  return true;
}

struct RenderOptions {
  double cacheMegabytes = 1024.0;
  double cacheTimeoutSeconds = 30.0;
  std::string profile = "compat";
  unsigned drawThreads = 1;
  std::string imageCompression = "auto";
  int imageCompressionLevel = kDefaultImageCompressionLevel;
  // Test hooks: a slow or stalled render process.
  double slowMillisecondsPerPacket = 0.0;
  int slowIndex = -1;               // this render process (index among renders) draws
  double slowFactor = 10.0;         // this many times slower
  std::uint64_t slowFromFrame = 0;  // the tiles of frames [from, to)
  std::uint64_t slowToFrame = 0;
  int stallIndex = -1;  // which render process (index among renders) stalls
  long stallAfterPackets = 0;
};

RenderCoreConfig coreConfig(const RenderOptions& options, const Job& job) {
  RenderCoreConfig config;
  config.cacheCapBytes = static_cast<std::uint64_t>(options.cacheMegabytes * 1024.0 * 1024.0);
  config.cacheTimeout =
      std::chrono::milliseconds(static_cast<long>(options.cacheTimeoutSeconds * 1000.0));
  if (options.stallIndex == job.indexInRole()) {
    config.stallAfterPackets = static_cast<std::uint64_t>(std::max(0L, options.stallAfterPackets));
  }
  return config;
}

class RenderProcess final : public WorkerProcess {
 public:
  RenderProcess(Job& job, const std::string& datasetPath, const RenderOptions& options)
      : job_(job),
        options_(options),
        dataset_(Dataset::open(datasetPath, DatasetParts::TopLevel)),
        core_(coreConfig(options, job), job.peers(), job.worldRank(), dataset_.topLevelCells(),
              assignPacketOwners(dataset_.topLevelCells(), job.layout().datasend,
                                 dataset_.packetCount()),
              dataset_.statisticalPackets()) {
    // Fail before the handshake on an option that cannot work.
    (void)parseProfile(options.profile);
  }

  std::string readyDetail() const override {
    return renderer_->describe() + ", cache cap " + std::to_string(core_.cache().capBytes() >> 20) +
           " MiB";
  }

  void begin(const v1::RunSettings& settings) override {
    settings_.mode = splatModeFromProto(
        settings.mode() == v1::RENDER_MODE_UNSPECIFIED ? v1::RENDER_MODE_POINTS : settings.mode());
    settings_.sizeScale = settings.size_scale() > 0.0f ? settings.size_scale() : 1.0f;
    settings_.lighting = !settings.unlit();
    settings_.edl = {settings.edl(), settings.edl_strength(), settings.edl_radius()};
    run_ = settings;
    compressImages_ = compressesImages(parseImageCompression(options_.imageCompression),
                                       job_.onThisMachine(job_.displayRank()));
    const v1::Renderer kind = resolveRenderer(settings.renderer(), settings.mode());
    renderers_.push_back(
        makeTileRenderer(kind, parseProfile(options_.profile), options_.drawThreads));
    if (settings.mode() == v1::RENDER_MODE_STATISTICAL || settings.statistical_hierarchy()) {
      classes_ = std::make_shared<const ClassTables>(dataset_.readStatisticalClasses());
      renderers_.back()->setStatisticalClasses(classes_);
    }
    kinds_.push_back(kind);
    renderer_ = renderers_.back().get();
    renderer_->warmUp(settings_);
  }

  void onMessage(Envelope& envelope) override {
    RenderEffects effects;
    switch (envelope.kind) {
      case MessageKind::DataPacket:
        receiveData(envelope, effects);
        break;
      case MessageKind::RenderPacket:
        core_.receivePacket(envelope.source, envelope.as<v1::RenderPacket>(), Clock::now(),
                            effects);
        break;
      default:
        throw ProtocolError(std::string("render got an unexpected ") +
                            messageKindName(envelope.kind) + " from rank " +
                            std::to_string(envelope.source));
    }
    apply(effects);
  }

  bool onIdle() override {
    RenderEffects effects;
    auto packet = core_.nextPacket(Clock::now(), effects);
    apply(effects);
    if (!packet) return false;
    draw(*packet);
    return true;
  }

  std::string idleActivity() const override { return "draw and send tiles"; }
  std::string summary() const override { return core_.summary(); }

 private:
  void receiveData(const Envelope& envelope, RenderEffects& effects) {
    const auto header = envelope.as<v1::DataPacketHeader>();
    checkDataPacketHeader(header, envelope.payload.size(), envelope.source);
    // What a byte cost this process before it can be drawn (T_n): its
    // transfer, shared among the parts by their size, and the CPU time that
    // checking and storing a byte took on the last data packets. Between
    // processes on one machine the transfer is a fast copy (or none: parts
    // read in place) and the storing is most of the cost; leaving it out made
    // the cost function send tiles wherever queues were shortest, and every
    // render process ended up holding most of the data (docs/scheduling.md §11).
    const double cpuStart = threadCpuSeconds();
    const auto bytes = static_cast<double>(header.byte_size());
    const double secondsPerSplat =
        (envelope.payloadSeconds / bytes + storeSecondsPerByte_) * sizeof(Splat);
    const SharedSegmentView* shared =
        header.has_shared() ? &sharedView(header.shared(), envelope.source, sharedViews_) : nullptr;
    const SharedSegmentView* groups =
        header.has_shared_groups()
            ? &sharedView(header.shared_groups(), envelope.source, sharedGroupViews_)
            : nullptr;
    const auto* payload = reinterpret_cast<const Splat*>(envelope.payload.data());
    // Per cell of the packet: its extent once every part is stored (a copy
    // makes room once), and the span of the parts stored, whose groups a
    // renderer drawing in place maps and takes once (a packet carries many
    // ranges of a cell).
    struct CellIntake {
      std::size_t room = 0;
      std::size_t from = std::numeric_limits<std::size_t>::max(), to = 0;
      std::uint64_t groupsOffset = 0;
      bool hasNormals = false;
    };
    std::map<std::uint32_t, CellIntake> cells;
    for (const v1::DataPart& part : header.parts()) {
      std::size_t& room = cells[part.top_level_cell()].room;
      room = std::max<std::size_t>(room, part.first_splat() + part.splat_count());
    }
    for (const v1::DataPart& part : header.parts()) {
      const auto count = static_cast<std::size_t>(part.splat_count());
      std::span<const Splat> splats;
      if (shared != nullptr) {
        const auto place = shared->bytes(part.shared_offset(), count * sizeof(Splat));
        splats = {reinterpret_cast<const Splat*>(place.data()), count};
      } else {
        splats = {payload, count};
        payload += count;
      }
      CellIntake& cell = cells[part.top_level_cell()];
      if (storePart(part, splats, shared == nullptr, groups != nullptr, cell.room,
                    secondsPerSplat * static_cast<double>(part.splat_count()), envelope.source,
                    effects)) {
        cell.from = std::min<std::size_t>(cell.from, part.first_splat());
        cell.to = std::max<std::size_t>(cell.to, part.first_splat() + count);
        cell.groupsOffset = part.shared_groups_offset();
        cell.hasNormals = part.shared_has_normals();
      }
    }
    if (groups != nullptr) {
      for (const auto& [cell, intake] : cells) {
        const std::size_t extent = core_.heldExtent(cell);
        if (intake.to == 0 || extent == 0) continue;  // nothing stored, or dropped since
        const auto block = groups->bytes(intake.groupsOffset, PointGroups::blockBytes(extent));
        // The groups the parts lie in: the rest is mapped as other parts arrive.
        const std::size_t from = intake.from / PointGroups::kPad * PointGroups::kPad;
        SharedSegmentView::populate(
            block.subspan(PointGroups::blockBytes(from),
                          PointGroups::blockBytes(intake.to) - PointGroups::blockBytes(from)));
        for (const auto& renderer : renderers_) {
          if (renderer->viewsInPlace()) {
            renderer->viewCell(cell, reinterpret_cast<const float*>(block.data()), extent,
                               intake.hasNormals);
          }
        }
      }
    }
    if (header.byte_size() >= kMinTransferSampleBytes) {
      storeSecondsPerByte_ =
          movingAverage(storeSecondsPerByte_, (threadCpuSeconds() - cpuStart) / bytes);
    }
  }

  // The segment a data-send process's header names, mapped on first use. Its
  // segments stay the same while it runs: cells drawn in place point into them.
  const SharedSegmentView& sharedView(const v1::SharedSegment& named, int source,
                                      std::map<int, SharedSegmentView>& views) {
    const SharedSegmentId id{named.pid(), named.fd(), named.inode(), named.byte_size()};
    SharedSegmentView& view = views[source];
    if (view.mapped() && view.id() == id) return view;
    if (view.mapped()) {
      throw ProtocolError("data-send rank " + std::to_string(source) +
                          " named another shared segment than before");
    }
    try {
      view = SharedSegmentView(id, "data-send rank " + std::to_string(source));
    } catch (const ProtocolError& error) {
      // Its data-send ended after sending: lost, as when a payload never comes.
      if (!processRuns(id.pid)) throw PeerSilentError(source, error.what());
      throw;
    }
    return view;
  }

  // `carried`: the bytes came in a payload, so their checksum is checked;
  // parts read in place were checked when their data-send loaded them.
  // `inPlace`: renderers that draw in place take the cell from the
  // data-send's groups afterwards; the others are written the splats.
  // `room`: the cell's extent once the data packet is stored. True when the
  // part was stored.
  bool storePart(const v1::DataPart& part, std::span<const Splat> splats, bool carried,
                 bool inPlace, std::size_t room, double seconds, int source,
                 RenderEffects& effects) {
    const std::uint32_t cell = part.top_level_cell();
    const auto first = static_cast<std::uint32_t>(part.first_splat());
    const auto count = static_cast<std::uint32_t>(part.splat_count());
    const bool wholePacket =
        cell < dataset_.packetCount() && first == 0 && count == core_.packetSplats(cell);
    if (carried && (checksum64(splats.data(), splats.size_bytes()) != part.checksum() ||
                    (wholePacket && part.checksum() != dataset_.packetChecksum(cell)))) {
      throw ProtocolError("data packet for top-level cell " + std::to_string(cell) + " from rank " +
                          std::to_string(source) + " (splats " + std::to_string(first) + "+" +
                          std::to_string(count) + ") fails its checksum");
    }
    const DataVerdict verdict =
        core_.receiveData(cell, first, count, seconds, Clock::now(), effects);
    // Evicted cells' buffers go first (the cell itself when it was dropped).
    for (std::uint32_t victim : effects.released) releaseEverywhere(victim);
    effects.released.clear();
    if (verdict != DataVerdict::Store) return false;
    const std::size_t extent = core_.heldExtent(cell);
    bool populated = carried;
    for (const auto& renderer : renderers_) {
      if (inPlace && renderer->viewsInPlace()) continue;
      if (!populated) SharedSegmentView::populate(std::as_bytes(splats));
      populated = true;
      renderer->writeToCell(cell, first, splats, std::max(room, extent));
    }
    return true;
  }

  void draw(const ReadyPacket& ready) {
    const v1::RenderPacket& packet = ready.packet;
    std::vector<DrawRange> ranges;
    ranges.reserve(static_cast<std::size_t>(packet.range_count_size()));
    const auto table = dataset_.topLevelCells();
    for (int i = 0; i < packet.range_count_size(); ++i) {
      const std::uint32_t cell = packet.range_top_level(i);
      const bool section =
          cell < table.size() && inInstancedSection(table[cell], packet.range_offset(i));
      ranges.push_back({cell, packet.range_offset(i), packet.range_count(i), section});
    }
    if (options_.slowMillisecondsPerPacket > 0.0) {
      std::this_thread::sleep_for(
          std::chrono::duration<double, std::milli>(options_.slowMillisecondsPerPacket));
    }
    RenderSettings settings = settings_;
    const v1::RenderMode mode =
        packet.has_frame_settings() && packet.frame_settings().mode() != v1::RENDER_MODE_UNSPECIFIED
            ? packet.frame_settings().mode()
            : run_.mode();
    settings.mode =
        splatModeFromProto(mode == v1::RENDER_MODE_UNSPECIFIED ? v1::RENDER_MODE_POINTS : mode);
    useRendererFor(mode, settings);
    // The display's render cache asks for depth; blended tiles have no single
    // visible surface, so they come without and the cache skips that frame.
    settings.keepDepth = packet.has_frame_settings() && packet.frame_settings().tile_depth() &&
                         settings.mode != SplatMode::Blended;
    RenderStats stats = renderer_->render(packet.camera(), packet.rect(), ranges, settings);
    if (options_.slowIndex == job_.indexInRole() && packet.frame_id() >= options_.slowFromFrame &&
        packet.frame_id() < options_.slowToFrame && options_.slowFactor > 1.0) {
      // As if drawing were this much slower (a node shared with another
      // job): the time is measured and reported like real drawing.
      const double extra = stats.seconds * (options_.slowFactor - 1.0);
      std::this_thread::sleep_for(std::chrono::duration<double>(extra));
      stats.seconds += extra;
    }
    RenderEffects effects;
    v1::TileImageHeader header =
        core_.packetDrawn(ready, stats.splats, stats.seconds, Clock::now(), effects);
    const bool part = header.format() == v1::PIXEL_FORMAT_POINT_WORDS64;
    const auto words = renderer_->pointWords();
    if (part &&
        words.size() != static_cast<std::size_t>(packet.rect().width()) * packet.rect().height()) {
      throw ProtocolError(
          "a part of a split tile needs the cpu point kernel without eye-dome "
          "lighting; this render process draws with " +
          renderer_->describe());
    }
    auto payload = std::make_shared<std::vector<std::byte>>();
    // Only the box drawn in, as runs where they are fewer bytes: a part
    // draws some of its tile's cells, a tile some of its sky, and the
    // display's link is what limits many render processes. A display on
    // this machine gets the box itself: memory is no link worth the CPU that
    // runs cost on both sides (8 % of the frame rate on two cores).
    const bool runsPay = !job_.onThisMachine(job_.displayRank());
    const auto sendBox = [&](const PixelBox& box, std::span<const std::byte> tile,
                             std::span<const std::byte> empty) {
      const v1::TileRect& rect = packet.rect();
      v1::TileRect& drawn = *header.mutable_drawn_rect();
      drawn.set_x(rect.x() + box.x);
      drawn.set_y(rect.y() + box.y);
      drawn.set_width(box.width);
      drawn.set_height(box.height);
      std::vector<std::byte> runs;
      if (runsPay) runs = encodePixelRuns(tile, empty.size(), rect.width(), box, empty);
      if (runsPay && runs.size() < std::size_t{box.width} * box.height * empty.size()) {
        header.set_runs_bytes(runs.size());
        *payload = std::move(runs);
      } else {
        *payload = pixelsInBox(tile, empty.size(), rect.width(), box);
      }
    };
    if (part) {
      constexpr std::uint64_t kEmpty = kEmptyPixel;
      sendBox(drawnWordsBox(words, packet.rect().width(), packet.rect().height()),
              std::as_bytes(words), std::as_bytes(std::span(&kEmpty, 1)));
    } else if (!settings.keepDepth && clearIsFrameBackground(settings)) {
      // The box of what differs from the background: the display shows the
      // background around it, as it would have from these pixels.
      const auto rgba = renderer_->pixels();
      sendBox(drawnRgbaBox(rgba, packet.rect().width(), packet.rect().height(), kFrameBackground),
              std::as_bytes(rgba), std::as_bytes(std::span(kFrameBackground)));
    } else {
      const auto pixels = std::as_bytes(renderer_->pixels());
      const auto depths = settings.keepDepth ? renderer_->depths() : std::span<const float>();
      if (settings.keepDepth) header.set_depth(v1::DEPTH_FORMAT_EYE_FLOAT32);
      payload->reserve(pixels.size() + depths.size_bytes());
      payload->insert(payload->end(), pixels.begin(), pixels.end());
      payload->insert(payload->end(), reinterpret_cast<const std::byte*>(depths.data()),
                      reinterpret_cast<const std::byte*>(depths.data()) + depths.size_bytes());
    }
    if (compressImages_ && !payload->empty()) {
      std::vector<std::byte> frame = compressImageBytes(*payload, options_.imageCompressionLevel);
      if (!frame.empty()) {
        header.set_uncompressed_bytes(payload->size());
        header.set_compressed_bytes(frame.size());
        *payload = std::move(frame);
      }
    }
    const std::span<const std::byte> bytes(*payload);
    job_.sends().post(job_.displayRank(), MessageKind::TileImage, header, bytes,
                      std::move(payload));
    apply(effects);
  }

  // A served frame's mode may need the other renderer (auto: the cpu kernel
  // draws points, OSMesa the rest). The new one takes over every cell held
  // and both stay, each receiving what arrives, so clients drawing different
  // modes at once cost memory, not a copy per tile; each mode's frames stay
  // those of the renderer the reference uses for it.
  void useRendererFor(v1::RenderMode mode, const RenderSettings& settings) {
    const v1::Renderer kind = resolveRenderer(run_.renderer(), mode);
    for (std::size_t i = 0; i < kinds_.size(); ++i) {
      if (kinds_[i] == kind) {
        renderer_ = renderers_[i].get();
        return;
      }
    }
    auto next = makeTileRenderer(kind, parseProfile(options_.profile), options_.drawThreads);
    if (classes_) next->setStatisticalClasses(classes_);
    next->warmUp(settings);
    renderer_->forEachCell(
        [&](std::uint32_t id, std::span<const Splat> splats) { next->uploadCell(id, splats); });
    renderers_.push_back(std::move(next));
    kinds_.push_back(kind);
    renderer_ = renderers_.back().get();
  }

  void releaseEverywhere(std::uint32_t cell) {
    for (const auto& renderer : renderers_) renderer->releaseCell(cell);
  }

  // Frees what the core dropped and sends what it asked for.
  void apply(RenderEffects& effects) {
    for (std::uint32_t cell : effects.released) releaseEverywhere(cell);
    job_.sends().post(effects.messages);
  }

  Job& job_;
  RenderOptions options_;
  Dataset dataset_;
  RenderCore core_;
  double storeSecondsPerByte_ = 0.0;                   // CPU to check and store a byte of data
  std::map<int, SharedSegmentView> sharedViews_;       // by data-send rank
  std::map<int, SharedSegmentView> sharedGroupViews_;  // the same in the kernel's layout
  // Made once the run's settings are known; a second one when a served frame
  // asks for a mode the first cannot draw. renderer_ drew the last tile.
  std::vector<std::unique_ptr<TileRenderer>> renderers_;
  std::vector<v1::Renderer> kinds_;
  TileRenderer* renderer_ = nullptr;
  RenderSettings settings_;
  v1::RunSettings run_;
  bool compressImages_ = false;  // tile images go as zstd frames (--image-compression)
  std::shared_ptr<const ClassTables> classes_;  // a dataset built with --statistical
};

}  // namespace

int runRenderMain(int argc, char** argv) {
  RenderOptions options;
  return runWorkerMain(
      argc, argv, v1::ROLE_RENDER, "Pointillist render process (started by deploy/run.sh)",
      [&](CLI::App& app) {
        app.add_option("--cache-mb", options.cacheMegabytes,
                       "Memory cap of the top-level cell cache")
            ->check(CLI::PositiveNumber);
        app.add_option("--cache-timeout", options.cacheTimeoutSeconds,
                       "Seconds after which an unused cell is dropped")
            ->check(CLI::PositiveNumber);
        app.add_option("--gl-profile", options.profile, "OSMesa context profile: compat or core");
        app.add_option("--draw-threads", options.drawThreads,
                       "Threads drawing each tile with the cpu renderer")
            ->check(CLI::Range(1, 64));
        app.add_option("--image-compression", options.imageCompression,
                       "Tile images to the display as zstd frames: auto (where the display is on "
                       "another machine: its link is what many render processes fill), zstd "
                       "(always) or off")
            ->check(CLI::IsMember({"auto", "zstd", "off"}));
        app.add_option(
               "--image-compression-level", options.imageCompressionLevel,
               "zstd level of compressed tile images (negative: faster, fewer times smaller)")
            ->check(CLI::Range(-7, 19));
        app.add_option("--slow-ms", options.slowMillisecondsPerPacket)->group("");
        app.add_option("--slow-index", options.slowIndex)->group("");
        app.add_option("--slow-factor", options.slowFactor)->group("");
        app.add_option("--slow-from-frame", options.slowFromFrame)->group("");
        app.add_option("--slow-to-frame", options.slowToFrame)->group("");
        app.add_option("--stall-index", options.stallIndex)->group("");
        app.add_option("--stall-after", options.stallAfterPackets)->group("");
      },
      [&](Job& job, const std::string& datasetPath) {
        return std::make_unique<RenderProcess>(job, datasetPath, options);
      });
}

}  // namespace pointillist::render
