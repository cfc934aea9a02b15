// Every protocol message survives serialization unchanged, and bytes that are
// not a message are refused.
#include <gtest/gtest.h>

#include "common/errors.hpp"
#include "common/messages.hpp"
#include "pointillist.pb.h"

namespace pointillist {
namespace {

v1::Camera sampleCamera() {
  v1::Camera camera;
  camera.mutable_eye()->set_x(1.5f);
  camera.mutable_eye()->set_y(-2.0f);
  camera.mutable_eye()->set_z(3.25f);
  camera.mutable_target()->set_z(-1.0f);
  camera.mutable_up()->set_y(1.0f);
  camera.set_fov_y_degrees(45.0f);
  camera.set_near_plane(0.01f);
  camera.set_far_plane(1000.0f);
  camera.set_image_width(1280);
  camera.set_image_height(720);
  return camera;
}

template <class M>
M roundTrip(const M& message) {
  std::string bytes;
  EXPECT_TRUE(message.SerializeToString(&bytes));
  M parsed;
  EXPECT_TRUE(parsed.ParseFromString(bytes));
  EXPECT_EQ(parsed.SerializeAsString(), bytes);
  return parsed;
}

TEST(Messages, RenderPacketRoundTripsWithAllRanges) {
  v1::RenderPacket packet;
  packet.set_frame_id(123456789012ull);
  packet.set_tile_id(17);
  *packet.mutable_camera() = sampleCamera();
  packet.mutable_rect()->set_x(320);
  packet.mutable_rect()->set_y(180);
  packet.mutable_rect()->set_width(160);
  packet.mutable_rect()->set_height(90);
  packet.set_packet_id(77);
  for (std::uint32_t i = 0; i < 1000; ++i) {
    packet.add_range_top_level(i % 37);
    packet.add_range_offset(i * 64);
    packet.add_range_count(i + 1);
  }
  packet.add_need_top_level(3);
  packet.add_need_first(0);
  packet.add_need_count(100);
  packet.set_total_splats(500500);
  const auto parsed = roundTrip(packet);
  EXPECT_EQ(parsed.range_offset_size(), 1000);
  EXPECT_EQ(parsed.range_offset(999), 999u * 64u);
  EXPECT_EQ(parsed.camera().eye().z(), 3.25f);
  EXPECT_EQ(parsed.camera().image_width(), 1280u);
  EXPECT_EQ(parsed.packet_id(), 77u);
}

TEST(Messages, ControlMessagesRoundTrip) {
  v1::Handshake hello;
  hello.set_protocol_version(v1::PROTOCOL_VERSION_CURRENT);
  hello.set_role(v1::ROLE_RENDER);
  hello.set_world_rank(5);
  hello.set_hostname("node-3");
  for (std::uint32_t count : {1u, 2u, 1u, 4u}) hello.add_layout(count);
  const auto parsedHello = roundTrip(hello);
  EXPECT_EQ(parsedHello.role(), v1::ROLE_RENDER);
  EXPECT_EQ(parsedHello.layout_size(), 4);
  EXPECT_EQ(parsedHello.hostname(), "node-3");

  v1::RenderReport report;
  report.set_render_rank(6);
  report.set_workload_splats(1'000'000'000'000ull);
  report.add_loaded_top_level(4);
  report.add_loaded_first(128);
  report.add_loaded_count(64);
  report.add_evicted_cells(9);
  report.set_seconds_per_splat(2.5e-8);
  const auto parsedReport = roundTrip(report);
  EXPECT_EQ(parsedReport.workload_splats(), 1'000'000'000'000ull);
  EXPECT_DOUBLE_EQ(parsedReport.seconds_per_splat(), 2.5e-8);
  EXPECT_EQ(parsedReport.evicted_cells(0), 9u);
  EXPECT_EQ(parsedReport.loaded_first(0), 128u);

  v1::ErrorReport error;
  error.set_origin_rank(3);
  error.set_origin_role(v1::ROLE_DATASEND);
  error.set_message("dataset.bin: checksum mismatch");
  EXPECT_EQ(roundTrip(error).message(), "dataset.bin: checksum mismatch");

  v1::SendOrder order;
  order.set_render_rank(7);
  order.add_range_top_level(11);
  order.add_range_first(40);
  order.add_range_count(8);
  EXPECT_EQ(roundTrip(order).range_top_level(0), 11u);
  EXPECT_EQ(roundTrip(order).range_first(0), 40u);

  v1::HandshakeReply reply;
  reply.set_accepted(true);
  reply.mutable_settings()->set_mode(v1::RENDER_MODE_SPLATS);
  reply.mutable_settings()->set_scheduler(v1::SCHEDULER_EQUALIZER);
  reply.mutable_settings()->set_lod_pixels(1.5f);
  const auto parsedReply = roundTrip(reply);
  EXPECT_EQ(parsedReply.settings().mode(), v1::RENDER_MODE_SPLATS);
  EXPECT_EQ(parsedReply.settings().scheduler(), v1::SCHEDULER_EQUALIZER);
  EXPECT_EQ(parsedReply.settings().lod_pixels(), 1.5f);

  v1::TileTask task;
  task.set_frame_id(8);
  *task.mutable_camera() = sampleCamera();
  task.set_timestamp_ns(1'700'000'000'000'000'000ll);
  EXPECT_EQ(roundTrip(task).timestamp_ns(), 1'700'000'000'000'000'000ll);
}

TEST(Messages, GarbageDoesNotParse) {
  v1::RenderPacket packet;
  // Field 1 as a length-delimited string whose length runs past the end.
  EXPECT_FALSE(packet.ParseFromString(std::string("\x0a\x7f\x01\x02", 4)));
  // A varint that never ends.
  EXPECT_FALSE(packet.ParseFromString(std::string(12, '\xff')));
}

TEST(Messages, ProtocolVersionIsSet) {
  EXPECT_GE(static_cast<int>(v1::PROTOCOL_VERSION_CURRENT), 1);
}

TEST(Outbox, KeepsOrderSharesOneMessageAmongDestinationsAndChecksTypes) {
  Outbox out;
  v1::RenderReport report;
  report.set_sequence(3);
  out.send(std::vector<int>{1, 2, 5}, report);
  v1::SendOrder order;
  order.add_range_top_level(4);
  out.send(7, order);
  out.send(std::vector<int>{}, order);  // nobody to tell: nothing queued
  ASSERT_EQ(out.entries().size(), 2u);
  EXPECT_EQ(out.entries()[0].kind, MessageKind::RenderReport);
  EXPECT_EQ(out.entries()[0].destinations, (std::vector<int>{1, 2, 5}));
  EXPECT_EQ(out.entries()[0].as<v1::RenderReport>().sequence(), 3u);
  EXPECT_EQ(out.entries()[1].kind, MessageKind::SendOrder);
  EXPECT_THROW((void)out.entries()[1].as<v1::RenderReport>(), ProtocolError);
  const auto taken = out.take();
  EXPECT_EQ(taken.size(), 2u);
  EXPECT_TRUE(out.empty());
  EXPECT_STREQ(messageKindName(MessageKind::SendOrder), "SendOrder");
}

}  // namespace
}  // namespace pointillist
