// libFuzzer target: the dataset manifest parser (every role reads a dataset's
// manifest first). An InputError naming the file and line is the refusal a
// damaged manifest should get; anything else is a finding.
#include <cstddef>
#include <cstdint>
#include <string_view>

#include "common/dataset_manifest.hpp"
#include "common/errors.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  try {
    const auto manifest = pointillist::DatasetManifest::parse(text, "fuzz/manifest.txt");
    // What parses must print and parse again the same.
    const auto again = pointillist::DatasetManifest::parse(manifest.toText(), "fuzz/again.txt");
    if (again.toText() != manifest.toText()) __builtin_trap();
  } catch (const pointillist::InputError&) {
  }
  return 0;
}
