// Camera paths: the built-in ones frame the data; files round-trip, and a bad
// line is named.
#include "common/camera_path.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "common/errors.hpp"
#include "common/view_options.hpp"

namespace pointillist {
namespace {

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

// --loops plays the path over again: the same cameras, loop after loop.
TEST(CameraPath, LoopsRepeatThePathsCameras) {
  const SceneBounds bounds{{-10, -5, 0}, {10, 5, 3}};
  ViewOptions view;
  view.frames = 7;
  view.size = "64x36";
  const auto once = viewCameras(view, bounds);
  view.loops = 3;
  const auto thrice = viewCameras(view, bounds);
  ASSERT_EQ(once.size(), 7u);
  ASSERT_EQ(thrice.size(), 21u);
  for (std::size_t i = 0; i < thrice.size(); ++i) {
    EXPECT_EQ(thrice[i].SerializeAsString(), once[i % 7].SerializeAsString()) << i;
  }
  EXPECT_NE(once[0].SerializeAsString(), once[1].SerializeAsString());
  view.loops = 0;
  EXPECT_THROW((void)viewCameras(view, bounds), UsageError);
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
