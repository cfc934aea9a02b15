#include "service/web/browser_protocol.hpp"

#include <gtest/gtest.h>

#include <string>

namespace pointillist::service::web {
namespace {

TEST(BrowserProtocol, ParsesACamera) {
  const auto request = parseBrowserMessage(
      R"({"type":"camera","id":7,"eye":[1,2,3],"target":[0,0,0.5],"up":[0,0,1],"fov":40,)"
      R"("width":1280,"height":720})");
  EXPECT_EQ(request.id, 7u);
  EXPECT_FLOAT_EQ(request.camera.eye().y(), 2.0f);
  EXPECT_FLOAT_EQ(request.camera.target().z(), 0.5f);
  EXPECT_TRUE(request.camera.has_up());
  EXPECT_FLOAT_EQ(request.camera.fov_y_degrees(), 40.0f);
  EXPECT_EQ(request.width, 1280u);
  EXPECT_EQ(request.height, 720u);
}

TEST(BrowserProtocol, UpFovAndSizeAreOptional) {
  const auto request =
      parseBrowserMessage(R"({"type":"camera","id":0,"eye":[1,2,3],"target":[0,0,0]})");
  EXPECT_FALSE(request.camera.has_up());
  EXPECT_EQ(request.camera.fov_y_degrees(), 0.0f);
  EXPECT_EQ(request.width, 0u);
}

TEST(BrowserProtocol, RefusesMalformedMessages) {
  const char* bad[] = {
      "",
      "not json",
      "[1,2,3]",
      R"({"id":1,"eye":[1,2,3],"target":[0,0,0]})",
      R"({"type":"shutdown","id":1})",
      R"({"type":"camera","eye":[1,2,3],"target":[0,0,0]})",
      R"({"type":"camera","id":-1,"eye":[1,2,3],"target":[0,0,0]})",
      R"({"type":"camera","id":1.5,"eye":[1,2,3],"target":[0,0,0]})",
      R"({"type":"camera","id":1,"eye":[1,2],"target":[0,0,0]})",
      R"({"type":"camera","id":1,"eye":[1,2,3,4],"target":[0,0,0]})",
      R"({"type":"camera","id":1,"eye":"1,2,3","target":[0,0,0]})",
      R"({"type":"camera","id":1,"eye":[1,"x",3],"target":[0,0,0]})",
      R"({"type":"camera","id":1,"eye":[1,2,1e999],"target":[0,0,0]})",
      R"({"type":"camera","id":1,"eye":[0,0,0],"target":[0,0,0]})",
      R"({"type":"camera","id":1,"eye":[1,2,3],"target":[0,0,0],"fov":180})",
      R"({"type":"camera","id":1,"eye":[1,2,3],"target":[0,0,0],"width":100000})",
      R"({"type":"camera","id":1,"eye":[1,2,3],"target":[0,0,0],"width":8})",
      R"({"type":"camera","id":1,"eye":[1,2,3],"target":[0,0,0],"up":[0,0,0]})",
      R"({"type":"camera","id":1,"eye":[1,2,3],"target":[0,0,0],"mode":"statistical"})",
      R"({"type":"camera","id":1,"eye":[1,2,3],"target":[0,0,0],"mode":["splats"]})",
      R"({"type":"camera","id":1,"eye":[1,2,3],"target":[0,0,0],"lod":0})",
      R"({"type":"camera","id":1,"eye":[1,2,3],"target":[0,0,0],"lod":65})",
      R"({"type":"camera","id":1,"eye":[1,2,3],"target":[0,0,0],"lod":"fine"})",
  };
  for (const char* text : bad) {
    EXPECT_THROW(parseBrowserMessage(text), BrowserMessageError) << text;
  }
  EXPECT_THROW(parseBrowserMessage(std::string(kMaxBrowserMessageBytes + 1, ' ')),
               BrowserMessageError);
}

// The page's keys change this browser's mode and level of detail: they ride
// on the camera, and the relay sets them on the service when they change.
TEST(BrowserProtocol, ACameraMayCarryModeAndDetail) {
  const auto request = parseBrowserMessage(
      R"({"type":"camera","id":3,"eye":[1,2,3],"target":[0,0,0],"mode":"splats","lod":1.5})");
  EXPECT_EQ(request.mode, "splats");
  EXPECT_FLOAT_EQ(request.lodPixels, 1.5f);
  const auto plain =
      parseBrowserMessage(R"({"type":"camera","id":4,"eye":[1,2,3],"target":[0,0,0]})");
  EXPECT_TRUE(plain.mode.empty());
  EXPECT_EQ(plain.lodPixels, 0.0f);
}

TEST(BrowserProtocol, EscapesJson) {
  EXPECT_EQ(jsonEscape("a\"b\\c\n\x01"), "a\\\"b\\\\c\\n\\u0001");
  EXPECT_EQ(errorJson("bad \"x\"", 3), R"({"type":"error","message":"bad \"x\"","id":3})");
  EXPECT_EQ(errorJson("gone"), R"({"type":"error","message":"gone"})");
}

TEST(BrowserProtocol, FrameMetadata) {
  v1::FrameHeader header;
  header.set_frame_id(12);
  header.set_width(640);
  header.set_height(360);
  header.set_encoding(v1::ENCODING_JPEG);
  header.set_encoded_bytes(40000);
  header.set_splats(150000);
  const std::string json = frameJson(header, 5, 33.25, "ok");
  EXPECT_NE(json.find(R"("type":"frame","id":5,"status":"ok","frame_id":12)"), std::string::npos);
  EXPECT_NE(json.find(R"("bytes":40000,"splats":150000)"), std::string::npos);
  EXPECT_NE(json.find(R"("latency_ms":33.25)"), std::string::npos);
  header.set_mode("splats");
  header.set_lod_pixels(1.5f);
  EXPECT_NE(frameJson(header, 5, 1.0, "ok").find(R"("mode":"splats","lod_pixels":1.5,)"),
            std::string::npos);
  // The render cache's interim frames say so, with the share they filled
  // and the final frame's tiles already pasted in.
  EXPECT_NE(frameJson(header, 5, 1.0, "ok").find(R"("interim":false)"), std::string::npos);
  header.set_interim(true);
  header.set_cache_filled(0.75f);
  header.set_tiles_composed(3);
  EXPECT_NE(
      frameJson(header, 5, 1.0, "ok")
          .find(R"("interim":true,"cache_filled":0.750,"tiles_composed":3,"region":[0,0,0,0]})"),
      std::string::npos);
  // A region of the frame (the tiles that came since), to paint over it.
  header.set_region_x(10);
  header.set_region_y(20);
  header.set_region_width(30);
  header.set_region_height(40);
  EXPECT_NE(frameJson(header, 5, 1.0, "ok").find(R"("region":[10,20,30,40]})"), std::string::npos);
}

TEST(BrowserProtocol, InfoListsTheModesABrowserMaySwitchTo) {
  v1::DatasetInfo info;
  info.add_modes_available("points");
  info.add_modes_available("splats");
  info.set_lod_pixels(1.0f);
  const std::string json = infoJson(info, v1::FrameFormat{});
  EXPECT_NE(json.find(R"("lod_pixels":1,"modes_available":["points","splats"]})"),
            std::string::npos)
      << json;
}

}  // namespace
}  // namespace pointillist::service::web
