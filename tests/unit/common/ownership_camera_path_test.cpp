#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <numeric>

#include "common/camera_path.hpp"
#include "common/errors.hpp"
#include "common/ownership.hpp"

namespace pointillist {
namespace {

TEST(Ownership, ContiguousRunsOfAboutEqualBytes) {
  std::vector<TopLevelCell> cells(100);
  for (std::size_t i = 0; i < cells.size(); ++i) cells[i].byteSize = 1000 + (i % 7) * 300;
  for (std::uint32_t owners : {1u, 2u, 3u, 7u}) {
    const auto owner = assignOwners(cells, owners);
    std::vector<std::uint64_t> bytes(owners, 0);
    for (std::size_t i = 0; i < cells.size(); ++i) {
      ASSERT_LT(owner[i], owners);
      if (i > 0) {
        ASSERT_GE(owner[i], owner[i - 1]) << "contiguous runs";
      }
      bytes[owner[i]] += cells[i].byteSize;
    }
    const double mean =
        static_cast<double>(std::accumulate(bytes.begin(), bytes.end(), 0ull)) / owners;
    for (auto b : bytes) EXPECT_NEAR(static_cast<double>(b), mean, 2000.0);
  }
  EXPECT_THROW((void)assignOwners(cells, 0), UsageError);
}

TEST(CameraPath, BuiltinPathsFrameTheData) {
  const SceneBounds bounds{{-10, -5, 0}, {10, 5, 3}};
  for (const auto& name : builtinCameraPaths()) {
    const auto keys = builtinCameraPath(name, bounds, 12, defaultUpAxis(bounds));
    ASSERT_EQ(keys.size(), 12u);
    for (const auto& key : keys) {
      const Camera camera = cameraFromKey(key, bounds, 320, 200);
      EXPECT_NO_THROW(validateCamera(camera));
      // The target (inside the data) is in front of the eye and on screen.
      const glm::vec4 w = projectToWindow(camera, key.target);
      EXPECT_GT(w.w, 0.0f) << name;
      EXPECT_NEAR(w.x, 160.0f, 1.0f) << name;
    }
  }
  EXPECT_EQ(defaultUpAxis(bounds), glm::vec3(0, 0, 1));
  EXPECT_THROW((void)builtinCameraPath("spiral", bounds, 3, {0, 0, 1}), UsageError);
}

TEST(CameraPath, FileRoundTripsAndBadLinesNameTheLine) {
  const auto dir = std::filesystem::temp_directory_path() / "pointillist-camera-path-test";
  std::filesystem::create_directories(dir);
  const SceneBounds bounds{{-1, -1, -1}, {1, 1, 1}};
  const auto keys = builtinCameraPath("orbit", bounds, 5, {0, 1, 0});
  writeCameraPath(dir / "path.txt", keys);
  const auto read = readCameraPath(dir / "path.txt", {0, 1, 0});
  ASSERT_EQ(read.size(), keys.size());
  for (std::size_t i = 0; i < keys.size(); ++i) {
    EXPECT_NEAR(glm::length(read[i].eye - keys[i].eye), 0.0f, 1e-5f);
    EXPECT_NEAR(glm::length(read[i].target - keys[i].target), 0.0f, 1e-5f);
  }
  {
    std::ofstream bad(dir / "bad.txt");
    bad << "# comment\n0 0 5 0 0 0\n0 0 5 0 0\n";
  }
  try {
    (void)readCameraPath(dir / "bad.txt", {0, 1, 0});
    FAIL();
  } catch (const InputError& error) {
    EXPECT_NE(std::string(error.what()).find("bad.txt: line 3"), std::string::npos) << error.what();
  }
  {
    std::ofstream bad(dir / "nan.txt");
    bad << "0 0 5 0 0 nan\n";
  }
  EXPECT_THROW((void)readCameraPath(dir / "nan.txt", {0, 1, 0}), InputError);
  std::filesystem::remove_all(dir);
}

TEST(CameraPath, ImageSizeParsing) {
  EXPECT_EQ(parseImageSize("1280x720"), (std::pair<std::uint32_t, std::uint32_t>{1280, 720}));
  for (const char* bad : {"1280", "x720", "1280x", "0x10", "12a0x720", "99999x10"}) {
    EXPECT_THROW((void)parseImageSize(bad), UsageError) << bad;
  }
}

}  // namespace
}  // namespace pointillist
