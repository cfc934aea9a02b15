#pragma once
// Tile images compressed for the display's link (TileImageHeader.compressed_bytes):
// the payload a render would send (a box, runs, words) as one zstd frame. The
// link to a display on another machine is what limits many render processes
// at 4K (docs/scheduling.md §22), and drawn pixels compress well: rendered
// colours repeat along a surface (the city's 4K runs 3.5-3.8 times, the
// bunny's 10-13 times at level 1).
#include <cstddef>
#include <span>
#include <string>
#include <vector>

namespace pointillist {

// When tile images are compressed: auto where they cross a link (the display
// on another machine, as for runs), always, or never.
enum class ImageCompression { Auto, Zstd, Off };

// "auto", "zstd" or "off"; anything else is a UsageError naming the choices.
ImageCompression parseImageCompression(const std::string& text);
const char* imageCompressionName(ImageCompression compression);

// Whether compression is on for a display on this machine or elsewhere.
bool compressesImages(ImageCompression compression, bool displayOnThisMachine);

// The smallest payload worth compressing: below it the frame's own header
// and the work on both sides cost more than the bytes saved.
inline constexpr std::size_t kMinCompressedPayload = 512;

// zstd's own default: about level 1's speed on tile images, 5-8 % smaller.
inline constexpr int kDefaultImageCompressionLevel = 3;

// `bytes` as one zstd frame at `level` (zstd's scale: 1 fast, negative
// faster, up to 19), the frame carrying its content size. Empty when the
// frame would not be smaller than `bytes` (send them as they are).
std::vector<std::byte> compressImageBytes(std::span<const std::byte> bytes, int level);

// The bytes of one zstd frame of `frame`, which must expand to exactly
// `expectedBytes`: anything else (not zstd, corrupt, another size, trailing
// bytes) is a ProtocolError naming `what` (e.g. "tile image from rank 3").
std::vector<std::byte> decompressImageBytes(std::span<const std::byte> frame,
                                            std::size_t expectedBytes, const std::string& what);

}  // namespace pointillist
