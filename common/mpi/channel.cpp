#include "common/mpi/channel.hpp"

#include <algorithm>
#include <climits>
#include <cstdlib>
#include <cstring>
#include <thread>
#include <utility>

namespace pointillist {
namespace {

constexpr std::uint32_t kFrameMagic = 0x504E5431;  // "PNT1"
// Magic, the header's bytes when it travels on its own (0: it follows the
// prefix in the same message), the payload's bytes.
constexpr std::size_t kPrefixBytes = 16;
// A message's first part stays this small so that every MPI transport sends
// it eagerly: once matched it is whole, and the receives of the rest are
// posted at once, before any probe could match a part of it.
constexpr std::size_t kInlineFrameBytes = 2048;
constexpr int kPayloadTagOffset = 1000;

void putU32(char* out, std::uint32_t value) {
  for (int i = 0; i < 4; ++i) out[i] = static_cast<char>((value >> (8 * i)) & 0xFFu);
}
void putU64(char* out, std::uint64_t value) {
  for (int i = 0; i < 8; ++i) out[i] = static_cast<char>((value >> (8 * i)) & 0xFFu);
}
std::uint64_t getLE(const char* in, int bytes) {
  std::uint64_t value = 0;
  for (int i = 0; i < bytes; ++i) {
    value |= static_cast<std::uint64_t>(static_cast<unsigned char>(in[i])) << (8 * i);
  }
  return value;
}

std::chrono::microseconds envMicros(const char* name, std::chrono::microseconds fallback) {
  if (const char* text = std::getenv(name)) {
    char* end = nullptr;
    const long value = std::strtol(text, &end, 10);
    if (end != text && value > 0) return std::chrono::microseconds(value);
  }
  return fallback;
}

}  // namespace

void checkMpi(int code, const char* call) {
  if (code == MPI_SUCCESS) return;
  char text[MPI_MAX_ERROR_STRING] = {};
  int length = 0;
  if (MPI_Error_string(code, text, &length) != MPI_SUCCESS) {
    throw TransportError(std::string(call) + " failed with MPI error code " + std::to_string(code));
  }
  throw TransportError(std::string(call) +
                       " failed: " + std::string(text, static_cast<std::size_t>(length)));
}

Backoff::Backoff()
    : minSleep_(envMicros("POINTILLIST_POLL_MIN_US", std::chrono::microseconds(20))),
      maxSleep_(envMicros("POINTILLIST_POLL_MAX_US", std::chrono::microseconds(2000))),
      sleep_(minSleep_) {}

void Backoff::wait() {
  std::this_thread::sleep_for(sleep_);
  sleep_ = std::min(maxSleep_, sleep_ * 2);
}

void Backoff::wait(std::chrono::microseconds cap) {
  std::this_thread::sleep_for(std::min(sleep_, cap));
  sleep_ = std::min(maxSleep_, sleep_ * 2);
}

SendHandle::SendHandle(SendHandle&& other) noexcept
    : requests_(std::move(other.requests_)),
      destination_(other.destination_),
      header_(std::move(other.header_)),
      ownedPayload_(std::move(other.ownedPayload_)) {
  other.requests_.clear();
}

SendHandle& SendHandle::operator=(SendHandle&& other) noexcept {
  if (this != &other) {
    try {
      wait();
    } catch (...) {
      // A failed send surfaces on the peer; here we must not throw from a move.
    }
    requests_ = std::move(other.requests_);
    destination_ = other.destination_;
    header_ = std::move(other.header_);
    ownedPayload_ = std::move(other.ownedPayload_);
    other.requests_.clear();
  }
  return *this;
}

SendHandle::~SendHandle() {
  try {
    // A peer that has already shut down never receives a late message; give up
    // on it after a while instead of hanging the process on exit.
    if (!waitFor(std::chrono::seconds(5))) cancel();
  } catch (...) {
    // Destructors must not throw; the job's error path reports transport failures.
  }
}

void SendHandle::cancel() {
  for (MPI_Request& request : requests_) {
    if (request != MPI_REQUEST_NULL) {
      MPI_Cancel(&request);
      MPI_Request_free(&request);
    }
  }
  requests_.clear();
}

void SendHandle::abandon(std::vector<std::shared_ptr<const void>>& keep) {
  // MPI_Request_free lets an active send finish (or not) on its own; Open MPI
  // cannot cancel sends, and waiting on one to a dead peer never ends.
  for (MPI_Request& request : requests_) {
    if (request != MPI_REQUEST_NULL) MPI_Request_free(&request);
  }
  requests_.clear();
  if (header_) keep.push_back(std::shared_ptr<const void>(std::move(header_)));
  if (ownedPayload_) keep.push_back(std::move(ownedPayload_));
}

bool SendHandle::waitFor(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  Backoff backoff;
  while (!test()) {
    if (std::chrono::steady_clock::now() >= deadline) return false;
    backoff.wait(kTransferPoll);
  }
  return true;
}

bool SendHandle::test() {
  if (requests_.empty()) return true;
  int done = 0;
  checkMpi(
      MPI_Testall(static_cast<int>(requests_.size()), requests_.data(), &done, MPI_STATUSES_IGNORE),
      "MPI_Testall");
  if (done != 0) {
    requests_.clear();
    header_.reset();
    ownedPayload_.reset();
  }
  return done != 0;
}

void SendHandle::wait() {
  Backoff backoff;
  while (!test()) backoff.wait();
}

Channel::Channel(MPI_Comm comm, std::size_t maxChunkBytes)
    : comm_(comm), maxChunkBytes_(std::clamp<std::size_t>(maxChunkBytes, 1, INT_MAX)) {
  checkMpi(MPI_Comm_rank(comm_, &rank_), "MPI_Comm_rank");
  checkMpi(MPI_Comm_size(comm_, &size_), "MPI_Comm_size");
}

int Channel::payloadTag(MessageKind kind) {
  return static_cast<int>(kind) + kPayloadTagOffset;
}

SendHandle Channel::post(int dest, MessageKind kind, const google::protobuf::MessageLite& header,
                         std::span<const std::byte> payload) {
  SendHandle handle;
  handle.destination_ = dest;
  handle.header_ = std::make_unique<std::string>(kPrefixBytes, '\0');
  std::string& frame = *handle.header_;
  if (!header.AppendToString(&frame)) {
    throw ProtocolError(std::string("cannot serialize ") + messageKindName(kind) + " message");
  }
  if (frame.size() > static_cast<std::size_t>(INT_MAX)) {
    throw ProtocolError(std::string(messageKindName(kind)) + " header exceeds 2 GiB");
  }
  const bool inlineHeader = frame.size() <= kInlineFrameBytes;
  putU32(frame.data(), kFrameMagic);
  putU32(frame.data() + 4,
         inlineHeader ? 0u : static_cast<std::uint32_t>(frame.size() - kPrefixBytes));
  putU64(frame.data() + 8, payload.size());
  handle.requests_.reserve(2 + payload.size() / maxChunkBytes_ + 1);
  MPI_Request request = MPI_REQUEST_NULL;
  const int firstBytes = static_cast<int>(inlineHeader ? frame.size() : kPrefixBytes);
  checkMpi(
      MPI_Isend(frame.data(), firstBytes, MPI_BYTE, dest, static_cast<int>(kind), comm_, &request),
      "MPI_Isend(header)");
  handle.requests_.push_back(request);
  if (!inlineHeader) {
    // Large headers (render and data packets of many ranges) follow on the
    // payload tag, ahead of the payload's chunks.
    checkMpi(MPI_Isend(frame.data() + kPrefixBytes, static_cast<int>(frame.size() - kPrefixBytes),
                       MPI_BYTE, dest, payloadTag(kind), comm_, &request),
             "MPI_Isend(header)");
    handle.requests_.push_back(request);
  }
  for (std::size_t offset = 0; offset < payload.size(); offset += maxChunkBytes_) {
    const std::size_t chunk = std::min(maxChunkBytes_, payload.size() - offset);
    checkMpi(MPI_Isend(payload.data() + offset, static_cast<int>(chunk), MPI_BYTE, dest,
                       payloadTag(kind), comm_, &request),
             "MPI_Isend(payload)");
    handle.requests_.push_back(request);
  }
  return handle;
}

SendHandle Channel::post(int dest, MessageKind kind, const google::protobuf::MessageLite& header,
                         std::shared_ptr<const std::vector<std::byte>> payload) {
  std::span<const std::byte> view;
  if (payload) view = std::span<const std::byte>(payload->data(), payload->size());
  return post(dest, kind, header, view, std::move(payload));
}

SendHandle Channel::post(int dest, MessageKind kind, const google::protobuf::MessageLite& header,
                         std::span<const std::byte> payload, std::shared_ptr<const void> owner) {
  SendHandle handle = post(dest, kind, header, payload);
  handle.ownedPayload_ = std::move(owner);
  return handle;
}

void Channel::send(int dest, MessageKind kind, const google::protobuf::MessageLite& header,
                   std::span<const std::byte> payload) {
  SendHandle handle = post(dest, kind, header, payload);
  handle.wait();
}

Channel::Incoming Channel::startReceive(MPI_Message& message, MPI_Status& status) {
  int count = 0;
  checkMpi(MPI_Get_count(&status, MPI_BYTE, &count), "MPI_Get_count");
  Incoming incoming;
  Envelope& envelope = incoming.envelope;
  envelope.source = status.MPI_SOURCE;
  envelope.kind = static_cast<MessageKind>(status.MPI_TAG);
  incoming.started = std::chrono::steady_clock::now();
  incoming.allowed = payloadTimeout_;
  // On the heap, so that a cancelled receive's buffer can be kept as it is
  // (a short std::string would hold its bytes inside the object).
  auto first = std::make_unique<std::string>(static_cast<std::size_t>(count), '\0');
  MPI_Request request = MPI_REQUEST_NULL;
  checkMpi(MPI_Imrecv(first->data(), count, MPI_BYTE, &message, &request), "MPI_Imrecv");
  // Our first parts are sent eagerly, so this is whole at once; a forged
  // larger one from a sender that then dies must not hold this process.
  Backoff backoff;
  for (int done = 0;;) {
    checkMpi(MPI_Test(&request, &done, MPI_STATUS_IGNORE), "MPI_Test(header)");
    if (done != 0) break;
    if (std::chrono::steady_clock::now() - incoming.started >= incoming.allowed) {
      MPI_Cancel(&request);
      MPI_Request_free(&request);
      static std::vector<std::unique_ptr<std::string>> orphans;
      orphans.push_back(std::move(first));
      throw PeerSilentError(envelope.source, "rank " + std::to_string(envelope.source) +
                                                 " began a " + std::to_string(count) + "-byte " +
                                                 messageKindName(envelope.kind) +
                                                 " header but did not finish it within " +
                                                 std::to_string(incoming.allowed.count()) + " ms");
    }
    backoff.wait(kTransferPoll);
  }
  if (first->size() < kPrefixBytes || getLE(first->data(), 4) != kFrameMagic) {
    throw ProtocolError("rank " + std::to_string(envelope.source) + " sent a " +
                        std::to_string(first->size()) + "-byte message on tag " +
                        std::to_string(static_cast<int>(envelope.kind)) +
                        " without the Pointillist frame prefix");
  }
  const std::uint64_t headerBytes = getLE(first->data() + 4, 4);
  const std::uint64_t payloadBytes = getLE(first->data() + 8, 8);
  if (headerBytes != 0 && first->size() != kPrefixBytes) {
    throw ProtocolError("rank " + std::to_string(envelope.source) + " sent a " +
                        messageKindName(envelope.kind) + " prefix of " +
                        std::to_string(first->size()) + " bytes that also names a " +
                        std::to_string(headerBytes) + "-byte header to follow");
  }
  // Everything of this message on the payload tag is received from here on:
  // posted now, before any later probe, its parts can match nothing else.
  const int tag = payloadTag(envelope.kind);
  if (headerBytes == 0) {
    envelope.header = first->substr(kPrefixBytes);
  } else {
    incoming.frame = std::make_unique<std::string>(headerBytes, '\0');
    checkMpi(MPI_Irecv(incoming.frame->data(), static_cast<int>(headerBytes), MPI_BYTE,
                       envelope.source, tag, comm_, &request),
             "MPI_Irecv(header)");
    incoming.requests.push_back(request);
  }
  envelope.payload.resize(payloadBytes);
  for (std::size_t offset = 0; offset < payloadBytes; offset += maxChunkBytes_) {
    const std::size_t chunk = std::min<std::size_t>(maxChunkBytes_, payloadBytes - offset);
    checkMpi(MPI_Irecv(envelope.payload.data() + offset, static_cast<int>(chunk), MPI_BYTE,
                       envelope.source, tag, comm_, &request),
             "MPI_Irecv(payload)");
    incoming.requests.push_back(request);
  }
  // The sender posted every part with the first, so these complete promptly
  // unless the sender died or its link is down mid-message.
  incoming.allowed =
      payloadTimeout_ +
      std::chrono::milliseconds(static_cast<long long>((headerBytes + payloadBytes) / 10'000));
  return incoming;
}

void Channel::abandon(Incoming& incoming) {
  bool named = false;
  for (MPI_Request& pending : incoming.requests) {
    if (pending == MPI_REQUEST_NULL) continue;
    MPI_Cancel(&pending);
    MPI_Request_free(&pending);
    named = true;
  }
  // The buffers may still be named by a cancelled receive: keep them.
  static std::vector<PayloadBytes> orphans;
  static std::vector<std::unique_ptr<std::string>> orphanFrames;
  if (named) {
    orphans.push_back(std::move(incoming.envelope.payload));
    if (incoming.frame) orphanFrames.push_back(std::move(incoming.frame));
  }
}

bool Channel::progress(Incoming& incoming) {
  if (incoming.complete) return true;
  if (!incoming.requests.empty()) {
    int done = 0;
    checkMpi(MPI_Testall(static_cast<int>(incoming.requests.size()), incoming.requests.data(),
                         &done, MPI_STATUSES_IGNORE),
             "MPI_Testall");
    if (done == 0) {
      if (std::chrono::steady_clock::now() - incoming.started < incoming.allowed) return false;
      const Envelope& envelope = incoming.envelope;
      const std::string what = incoming.frame
                                   ? std::to_string(incoming.frame->size()) + "-byte header and " +
                                         std::to_string(envelope.payload.size()) + "-byte payload"
                                   : std::to_string(envelope.payload.size()) + "-byte payload";
      abandon(incoming);
      throw PeerSilentError(envelope.source, "rank " + std::to_string(envelope.source) +
                                                 " began a " + messageKindName(envelope.kind) +
                                                 " message but did not send its " + what +
                                                 " within " +
                                                 std::to_string(incoming.allowed.count()) + " ms");
    }
  }
  if (incoming.frame) {
    incoming.envelope.header = std::move(*incoming.frame);
    incoming.frame.reset();
  }
  incoming.complete = true;
  incoming.envelope.payloadSeconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - incoming.started).count();
  return true;
}

std::optional<Envelope> Channel::takeArrived(int source, std::optional<MessageKind> kind) {
  // A sender taken for lost since: its unfinished payloads are not waited for.
  std::erase_if(incoming_, [&](Incoming& incoming) {
    if (!ignored_.contains(incoming.envelope.source)) return false;
    abandon(incoming);
    return true;
  });
  std::set<int> waiting;  // senders with an unfinished message the caller would take
  for (auto it = incoming_.begin(); it != incoming_.end(); ++it) {
    const int from = it->envelope.source;
    if ((source != MPI_ANY_SOURCE && from != source) || (kind && it->envelope.kind != *kind) ||
        waiting.contains(from)) {
      continue;
    }
    bool arrived = false;
    try {
      arrived = progress(*it);
    } catch (...) {
      incoming_.erase(it);
      throw;
    }
    if (!arrived) {
      waiting.insert(from);
      continue;
    }
    Envelope taken = std::move(it->envelope);
    incoming_.erase(it);
    return taken;
  }
  return std::nullopt;
}

std::optional<Envelope> Channel::tryReceive(int source, std::optional<MessageKind> kind) {
  if (!incoming_.empty()) {
    if (auto envelope = takeArrived(source, kind)) return envelope;
  }
  int flag = 0;
  MPI_Message message = MPI_MESSAGE_NULL;
  MPI_Status status;
  const int tag = kind ? static_cast<int>(*kind) : MPI_ANY_TAG;
  checkMpi(MPI_Improbe(source, tag, comm_, &flag, &message, &status), "MPI_Improbe");
  if (flag == 0) return std::nullopt;
  while (ignored_.contains(status.MPI_SOURCE)) {
    // Not waited for: a large message's bytes may sit with the lost sender
    // for ever. A receive that does not complete keeps its buffer.
    int count = 0;
    checkMpi(MPI_Get_count(&status, MPI_BYTE, &count), "MPI_Get_count");
    auto dropped = std::make_unique<PayloadBytes>(static_cast<std::size_t>(count));
    MPI_Request request = MPI_REQUEST_NULL;
    checkMpi(MPI_Imrecv(dropped->data(), count, MPI_BYTE, &message, &request), "MPI_Imrecv");
    int done = 0;
    checkMpi(MPI_Test(&request, &done, MPI_STATUS_IGNORE), "MPI_Test");
    if (done == 0) {
      MPI_Request_free(&request);
      static std::vector<std::unique_ptr<PayloadBytes>> orphans;
      orphans.push_back(std::move(dropped));
    }
    checkMpi(MPI_Improbe(source, tag, comm_, &flag, &message, &status), "MPI_Improbe");
    if (flag == 0) return std::nullopt;
  }
  if (status.MPI_TAG >= kPayloadTagOffset) {
    throw ProtocolError("payload chunk from rank " + std::to_string(status.MPI_SOURCE) +
                        " arrived without its header");
  }
  incoming_.push_back(startReceive(message, status));
  // Payloads normally follow their header at once: wait a moment, as the
  // caller would, before leaving it to arrive while the caller goes on.
  const auto patience = std::chrono::steady_clock::now() + kPayloadPatience;
  Backoff backoff;
  while (true) {
    if (auto envelope = takeArrived(source, kind)) return envelope;
    if (incoming_.empty() || incoming_.back().complete ||
        std::chrono::steady_clock::now() >= patience) {
      return std::nullopt;
    }
    backoff.wait(kTransferPoll);
  }
}

std::optional<Envelope> Channel::receive(int source, std::optional<MessageKind> kind,
                                         std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  Backoff backoff;
  while (true) {
    if (auto envelope = tryReceive(source, kind)) return envelope;
    if (std::chrono::steady_clock::now() >= deadline) return std::nullopt;
    backoff.wait();
  }
}

Envelope Channel::receiveOrThrow(int source, std::optional<MessageKind> kind,
                                 std::chrono::milliseconds timeout) {
  if (auto envelope = receive(source, kind, timeout)) return std::move(*envelope);
  throw TimeoutError(
      "no " + std::string(kind ? messageKindName(*kind) : "message") + " from " +
      (source == MPI_ANY_SOURCE ? std::string("any rank") : "rank " + std::to_string(source)) +
      " within " + std::to_string(timeout.count()) + " ms");
}

void Channel::barrier(std::chrono::milliseconds timeout) {
  MPI_Request request = MPI_REQUEST_NULL;
  checkMpi(MPI_Ibarrier(comm_, &request), "MPI_Ibarrier");
  waitFor(request, timeout, "barrier");
}

void Channel::waitFor(MPI_Request& request, std::chrono::milliseconds timeout, const char* what) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  Backoff backoff;
  while (true) {
    int done = 0;
    checkMpi(MPI_Test(&request, &done, MPI_STATUS_IGNORE), "MPI_Test");
    if (done != 0) return;
    if (std::chrono::steady_clock::now() >= deadline) {
      throw TimeoutError(std::string(what) + " did not complete within " +
                         std::to_string(timeout.count()) + " ms");
    }
    backoff.wait(kTransferPoll);
  }
}

}  // namespace pointillist
