#include "service/core/request_validation.hpp"

#include <gtest/gtest.h>

#include <string>
#include <vector>

namespace pointillist::service {
namespace {

v1::Request validRender() {
  v1::Request request;
  request.set_version(v1::SERVICE_VERSION_CURRENT);
  request.set_client_id("0123456789abcdef");
  request.set_request_id(7);
  *request.mutable_render()->mutable_camera() =
      cameraKeyMessage(CameraKey{{10, 0, 0}, {0, 0, 0}, {0, 0, 1}, 45.0f});
  return request;
}

v1::ErrorCode codeOf(const std::string& bytes, bool stream = false) {
  try {
    parseRequest(std::span(reinterpret_cast<const std::byte*>(bytes.data()), bytes.size()),
                 RequestLimits{}, stream);
  } catch (const RequestError& error) {
    return error.code();
  }
  return v1::ERROR_UNSPECIFIED;
}

v1::ErrorCode codeOf(const v1::Request& request, bool stream = false) {
  return codeOf(request.SerializeAsString(), stream);
}

TEST(RequestValidation, AcceptsAWellFormedRender) {
  EXPECT_EQ(codeOf(validRender()), v1::ERROR_UNSPECIFIED);
}

TEST(RequestValidation, RefusesBytesThatAreNotARequest) {
  EXPECT_EQ(codeOf(std::string("\xff\xff\xff\xff garbage", 13)), v1::ERROR_MALFORMED);
}

TEST(RequestValidation, RefusesMessagesOverTheCap) {
  v1::Request request = validRender();
  request.mutable_hello()->set_client_name(std::string(70 * 1024, 'x'));
  EXPECT_EQ(codeOf(request), v1::ERROR_TOO_LARGE);
}

TEST(RequestValidation, RefusesOtherVersions) {
  v1::Request request = validRender();
  request.set_version(v1::SERVICE_VERSION_CURRENT + 1);
  EXPECT_EQ(codeOf(request), v1::ERROR_VERSION_MISMATCH);
  request.set_version(0);
  EXPECT_EQ(codeOf(request), v1::ERROR_VERSION_MISMATCH);
}

TEST(RequestValidation, RefusesAnUnknownBody) {
  v1::Request request = validRender();
  request.clear_body();
  std::string bytes = request.SerializeAsString();
  // Field 99, length-delimited, empty: a body a newer client might send.
  bytes += std::string("\x9a\x06\x00", 3);
  EXPECT_EQ(codeOf(bytes), v1::ERROR_UNKNOWN_REQUEST);
}

// A client matches replies to requests by id: a refusal of a request that
// parsed carries that request's id.
TEST(RequestValidation, ARefusalNamesTheRequestItRefuses) {
  v1::Request request = validRender();
  request.set_request_id(41);
  request.mutable_render()->mutable_camera()->mutable_target()->set_x(10);  // eye == target
  const std::string bytes = request.SerializeAsString();
  try {
    parseRequest(std::span(reinterpret_cast<const std::byte*>(bytes.data()), bytes.size()),
                 RequestLimits{});
    FAIL() << "a camera with eye == target was accepted";
  } catch (const RequestError& error) {
    EXPECT_EQ(error.code(), v1::ERROR_INVALID_ARGUMENT);
    EXPECT_EQ(error.requestId(), 41u);
  }
}

TEST(RequestValidation, RefusesOptionsOutOfRange) {
  v1::Request request = validRender();
  request.clear_body();
  request.mutable_set_options()->set_lod_pixels(-1.0f);
  EXPECT_EQ(codeOf(request), v1::ERROR_INVALID_ARGUMENT);
  request.mutable_set_options()->set_lod_pixels(100.0f);
  EXPECT_EQ(codeOf(request), v1::ERROR_INVALID_ARGUMENT);
  request.mutable_set_options()->set_lod_pixels(2.0f);
  EXPECT_EQ(codeOf(request), v1::ERROR_UNSPECIFIED);
  request.mutable_set_options()->set_mode(std::string(100, 'm'));
  EXPECT_EQ(codeOf(request), v1::ERROR_INVALID_ARGUMENT);
  request.mutable_set_options()->set_mode("splats");
  request.mutable_set_options()->set_scheduler(std::string(100, 's'));
  EXPECT_EQ(codeOf(request), v1::ERROR_INVALID_ARGUMENT);
}

TEST(RequestValidation, AttachOnlyOnTheStreamAndNothingElseThere) {
  v1::Request attach = validRender();
  attach.mutable_attach();
  EXPECT_EQ(codeOf(attach, true), v1::ERROR_UNSPECIFIED);
  EXPECT_EQ(codeOf(attach, false), v1::ERROR_UNKNOWN_REQUEST);
  EXPECT_EQ(codeOf(validRender(), true), v1::ERROR_UNKNOWN_REQUEST);
}

TEST(RequestValidation, RequiresAClientIdExceptForHello) {
  v1::Request request = validRender();
  request.clear_client_id();
  EXPECT_EQ(codeOf(request), v1::ERROR_UNKNOWN_CLIENT);
  request.mutable_hello()->set_client_name("me");
  EXPECT_EQ(codeOf(request), v1::ERROR_UNSPECIFIED);
}

TEST(RequestValidation, RefusesBadCameras) {
  const auto withCamera = [](CameraKey key, float fov = 45.0f) {
    v1::Request request = validRender();
    *request.mutable_render()->mutable_camera() = cameraKeyMessage(key);
    request.mutable_render()->mutable_camera()->set_fov_y_degrees(fov);
    return request;
  };
  const float nan = std::numeric_limits<float>::quiet_NaN();
  EXPECT_EQ(codeOf(withCamera({{nan, 0, 0}, {0, 0, 0}, {0, 0, 1}})), v1::ERROR_INVALID_ARGUMENT);
  EXPECT_EQ(codeOf(withCamera({{1, 1, 1}, {1, 1, 1}, {0, 0, 1}})), v1::ERROR_INVALID_ARGUMENT);
  EXPECT_EQ(codeOf(withCamera({{0, 0, 5}, {0, 0, 0}, {0, 0, 1}})), v1::ERROR_INVALID_ARGUMENT);
  EXPECT_EQ(codeOf(withCamera({{5, 0, 0}, {0, 0, 0}, {0, 0, 1}}, 180.0f)),
            v1::ERROR_INVALID_ARGUMENT);
  v1::Request noCamera = validRender();
  noCamera.mutable_render()->clear_camera();
  EXPECT_EQ(codeOf(noCamera), v1::ERROR_INVALID_ARGUMENT);
}

TEST(RequestValidation, RefusesSizesAndEncodingsOutOfRange) {
  v1::Request request = validRender();
  request.mutable_render()->mutable_format()->set_width(8);
  EXPECT_EQ(codeOf(request), v1::ERROR_INVALID_ARGUMENT);
  request.mutable_render()->mutable_format()->set_width(100000);
  EXPECT_EQ(codeOf(request), v1::ERROR_INVALID_ARGUMENT);
  request.mutable_render()->mutable_format()->set_width(640);
  request.mutable_render()->mutable_format()->set_encoding(static_cast<v1::Encoding>(42));
  EXPECT_EQ(codeOf(request), v1::ERROR_INVALID_ARGUMENT);
  request.mutable_render()->mutable_format()->set_encoding(v1::ENCODING_JPEG);
  request.mutable_render()->mutable_format()->set_jpeg_quality(101);
  EXPECT_EQ(codeOf(request), v1::ERROR_INVALID_ARGUMENT);
  request.mutable_render()->mutable_format()->set_jpeg_quality(80);
  EXPECT_EQ(codeOf(request), v1::ERROR_UNSPECIFIED);
}

TEST(RequestValidation, PathsAreBuiltInOrExplicitNeverFiles) {
  v1::Request request = validRender();
  request.mutable_path()->set_builtin("/etc/passwd");
  request.mutable_path()->set_frames(4);
  EXPECT_EQ(codeOf(request), v1::ERROR_INVALID_ARGUMENT);
  request.mutable_path()->set_builtin("orbit");
  EXPECT_EQ(codeOf(request), v1::ERROR_UNSPECIFIED);
  request.mutable_path()->set_frames(0);
  EXPECT_EQ(codeOf(request), v1::ERROR_INVALID_ARGUMENT);
  request.mutable_path()->set_frames(100000);
  EXPECT_EQ(codeOf(request), v1::ERROR_INVALID_ARGUMENT);
  request.mutable_path()->mutable_cameras();
  EXPECT_EQ(codeOf(request), v1::ERROR_INVALID_ARGUMENT);  // no cameras
  *request.mutable_path()->mutable_cameras()->add_keys() = validRender().render().camera();
  EXPECT_EQ(codeOf(request), v1::ERROR_UNSPECIFIED);
}

TEST(RequestValidation, MergedFormatKeepsWhatTheUpdateLeavesZero) {
  v1::FrameFormat base;
  base.set_width(1280);
  base.set_height(720);
  base.set_encoding(v1::ENCODING_PNG);
  base.set_jpeg_quality(90);
  v1::FrameFormat update;
  update.set_encoding(v1::ENCODING_JPEG);
  const v1::FrameFormat merged = mergeFormat(base, update);
  EXPECT_EQ(merged.width(), 1280u);
  EXPECT_EQ(merged.height(), 720u);
  EXPECT_EQ(merged.encoding(), v1::ENCODING_JPEG);
  EXPECT_EQ(merged.jpeg_quality(), 90u);
}

TEST(RequestValidation, CameraKeysRoundTripAndTakeTheDefaultUp) {
  const CameraKey key{{1.5f, -2.0f, 3.25f}, {0.0f, 0.5f, 0.0f}, {0, 1, 0}, 60.0f};
  const CameraKey back = cameraKeyFromMessage(cameraKeyMessage(key), {0, 0, 1});
  EXPECT_EQ(back.eye, key.eye);
  EXPECT_EQ(back.target, key.target);
  EXPECT_EQ(back.up, key.up);
  EXPECT_EQ(back.fovYDegrees, key.fovYDegrees);
  v1::CameraKey noUp = cameraKeyMessage(key);
  noUp.clear_up();
  noUp.set_fov_y_degrees(0.0f);
  const CameraKey defaulted = cameraKeyFromMessage(noUp, {0, 0, 1});
  EXPECT_EQ(defaulted.up, glm::vec3(0, 0, 1));
  EXPECT_EQ(defaulted.fovYDegrees, 45.0f);
}

}  // namespace
}  // namespace pointillist::service
