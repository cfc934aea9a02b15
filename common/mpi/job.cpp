#include "common/mpi/job.hpp"

#include "common/core_share.hpp"
#include "common/peer_watch.hpp"
#include "common/run_settings.hpp"
#include "common/shared_packets.hpp"

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <set>
#include <sstream>

namespace pointillist {
namespace {

constexpr int kBootstrapMagic = 0x504E5442;  // "PNTB"
constexpr int kRoleCount = 5;                // v1::Role values 0..4

std::string hostName() {
  std::array<char, 256> name{};
  if (gethostname(name.data(), name.size() - 1) != 0) return "unknown-host";
  return name.data();
}

std::vector<std::uint32_t> layoutVector(const JobLayout& layout) {
  return {layout.display, layout.traverse, layout.datasend, layout.render};
}

}  // namespace

const char* roleName(v1::Role role) {
  switch (role) {
    case v1::ROLE_DISPLAY:
      return "display";
    case v1::ROLE_TRAVERSE:
      return "traverse";
    case v1::ROLE_DATASEND:
      return "datasend";
    case v1::ROLE_RENDER:
      return "render";
    default:
      return "unknown";
  }
}

std::string executableName(v1::Role role) {
  return std::string("pointillist-") + roleName(role);
}

double processCpuSeconds() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  const auto seconds = [](const timeval& value) {
    return static_cast<double>(value.tv_sec) + static_cast<double>(value.tv_usec) * 1e-6;
  };
  return seconds(usage.ru_utime) + seconds(usage.ru_stime);
}

Job::Job(int& argc, char**& argv, v1::Role role) : role_(role) {
  // Open MPI's MPI_Finalize waits in a fence for every process of the job;
  // after a lost process (mpirun --enable-recovery) the survivors would wait
  // there for ever. Each process has already said goodbye to the display by
  // then, so finalizing on its own loses nothing. A launcher's setting wins.
  setenv("OMPI_MCA_async_mpi_finalize", "1", 0);
  int provided = 0;
  checkMpi(MPI_Init_thread(&argc, &argv, MPI_THREAD_FUNNELED, &provided), "MPI_Init_thread");
  // Return codes instead of MPI's default abort, so every failure gets our message.
  checkMpi(MPI_Comm_set_errhandler(MPI_COMM_WORLD, MPI_ERRORS_RETURN), "MPI_Comm_set_errhandler");
  checkMpi(MPI_Comm_rank(MPI_COMM_WORLD, &worldRank_), "MPI_Comm_rank");
  checkMpi(MPI_Comm_size(MPI_COMM_WORLD, &worldSize_), "MPI_Comm_size");
  MPI_Request duplicated = MPI_REQUEST_NULL;
  checkMpi(MPI_Comm_idup(MPI_COMM_WORLD, &comm_, &duplicated), "MPI_Comm_idup");
  Channel::waitFor(duplicated, std::chrono::seconds(120), "communicator set-up");
  checkMpi(MPI_Comm_set_errhandler(comm_, MPI_ERRORS_RETURN), "MPI_Comm_set_errhandler");
  channel_ = std::make_unique<Channel>(comm_);
  sends_ = std::make_unique<SendQueue>(*channel_);

  int* appAttribute = nullptr;
  int found = 0;
  checkMpi(MPI_Comm_get_attr(MPI_COMM_WORLD, MPI_APPNUM, &appAttribute, &found),
           "MPI_Comm_get_attr(MPI_APPNUM)");
  appNumber_ = found != 0 && appAttribute != nullptr ? *appAttribute : -1;

  // Exchange roles without a blocking collective (those spin in Open MPI).
  const std::uint64_t machine = thisMachineIdentity();
  std::array<int, 6> mine{kBootstrapMagic,
                          static_cast<int>(role_),
                          appNumber_,
                          0,
                          static_cast<int>(static_cast<std::uint32_t>(machine)),
                          static_cast<int>(static_cast<std::uint32_t>(machine >> 32))};
  std::vector<int> all(static_cast<std::size_t>(worldSize_) * mine.size());
  MPI_Request request = MPI_REQUEST_NULL;
  checkMpi(MPI_Iallgather(mine.data(), static_cast<int>(mine.size()), MPI_INT, all.data(),
                          static_cast<int>(mine.size()), MPI_INT, comm_, &request),
           "MPI_Iallgather(roles)");
  Channel::waitFor(request, std::chrono::seconds(120), "role discovery");

  ranksByRole_.assign(kRoleCount, {});
  machines_.assign(static_cast<std::size_t>(worldSize_), 0);
  for (int rank = 0; rank < worldSize_; ++rank) {
    const int* entry = all.data() + static_cast<std::size_t>(rank) * mine.size();
    machines_[static_cast<std::size_t>(rank)] =
        static_cast<std::uint32_t>(entry[4]) |
        (std::uint64_t{static_cast<std::uint32_t>(entry[5])} << 32);
    if (entry[0] != kBootstrapMagic || entry[1] <= 0 || entry[1] >= kRoleCount) {
      throw CoordinatedError("rank " + std::to_string(rank) +
                             " is not a Pointillist process (bad start-up record); every rank "
                             "must be one of the pointillist-* role executables");
    }
    ranksByRole_[static_cast<std::size_t>(entry[1])].push_back(rank);
  }
  const auto& sameRole = ranksByRole_[static_cast<std::size_t>(role_)];
  for (std::size_t i = 0; i < sameRole.size(); ++i) {
    if (sameRole[i] == worldRank_) indexInRole_ = static_cast<int>(i);
  }
  layout_ = JobLayout{static_cast<std::uint32_t>(ranksByRole_[v1::ROLE_DISPLAY].size()),
                      static_cast<std::uint32_t>(ranksByRole_[v1::ROLE_TRAVERSE].size()),
                      static_cast<std::uint32_t>(ranksByRole_[v1::ROLE_DATASEND].size()),
                      static_cast<std::uint32_t>(ranksByRole_[v1::ROLE_RENDER].size())};
  try {
    layout_.validate();
  } catch (const ProtocolError& error) {
    throw CoordinatedError(std::string(error.what()) + " (started: " + layout_.toString() + ")");
  }
  checkMpi(MPI_Comm_split(comm_, static_cast<int>(role_), worldRank_, &roleComm_),
           "MPI_Comm_split(role)");
}

Job::~Job() {
  try {
    finalize();
  } catch (...) {
    // Nothing sensible is left to do while unwinding.
  }
}

void Job::finalize() {
  if (finalized_) return;
  finalized_ = true;
  if (sends_) sends_->drain(std::chrono::seconds(5));
  sends_.reset();
  if (roleComm_ != MPI_COMM_NULL) MPI_Comm_free(&roleComm_);
  channel_.reset();
  if (comm_ != MPI_COMM_NULL) MPI_Comm_free(&comm_);
  MPI_Finalize();
}

bool Job::onThisMachine(int rank) const {
  return rank >= 0 && rank < worldSize_ &&
         machines_[static_cast<std::size_t>(rank)] ==
             machines_[static_cast<std::size_t>(worldRank_)];
}

const std::vector<int>& Job::ranksOf(v1::Role role) const {
  return ranksByRole_.at(static_cast<std::size_t>(role));
}

PeerRanks Job::peers() const {
  PeerRanks peers;
  peers.display = displayRank();
  peers.traverses = ranksOf(v1::ROLE_TRAVERSE);
  peers.datasends = ranksOf(v1::ROLE_DATASEND);
  peers.renders = ranksOf(v1::ROLE_RENDER);
  return peers;
}

std::string Job::describe() const {
  return executableName(role_) + " rank " + std::to_string(worldRank_);
}

void Job::handshake(const HandshakeOptions& options) {
  Channel& channel = *channel_;
  if (role_ != v1::ROLE_DISPLAY) {
    v1::Handshake hello;
    hello.set_protocol_version(options.protocolVersion);
    hello.set_role(role_);
    hello.set_world_rank(worldRank_);
    hello.set_app_number(appNumber_);
    hello.set_hostname(hostName());
    hello.set_pid(static_cast<std::int64_t>(getpid()));
    for (std::uint32_t cpu : allowedCpus()) hello.add_cpus(cpu);
    for (std::uint32_t count : layoutVector(layout_)) hello.add_layout(count);
    channel.send(displayRank(), MessageKind::Handshake, hello);
    const auto reply =
        channel.receiveOrThrow(displayRank(), MessageKind::HandshakeReply, options.timeout)
            .as<v1::HandshakeReply>();
    if (!reply.accepted()) {
      throw CoordinatedError("the display refused this job: " + reply.reason());
    }
    runSettings_ = reply.settings();
    channel_->setPayloadTimeout(livenessOf(runSettings_).peerTimeout);
    return;
  }

  // Display: collect one handshake per peer, then answer all with one verdict.
  std::vector<std::string> problems;
  if (options.expectedLayout && !(*options.expectedLayout == layout_)) {
    problems.push_back("launcher asked for layout " + options.expectedLayout->toString() +
                       " but the job started " + layout_.toString());
  }
  std::vector<int> peers;
  for (int rank = 0; rank < worldSize_; ++rank) {
    if (rank != worldRank_) peers.push_back(rank);
  }
  std::vector<ProcessPlacement> placements{{worldRank_, role_, hostName(), allowedCpus()}};
  const auto deadline = std::chrono::steady_clock::now() + options.timeout;
  std::size_t received = 0;
  while (received < peers.size()) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    auto envelope = channel.receive(MPI_ANY_SOURCE, MessageKind::Handshake,
                                    std::max(left, std::chrono::milliseconds(0)));
    if (!envelope) {
      problems.push_back("only " + std::to_string(received) + " of " +
                         std::to_string(peers.size()) +
                         " processes completed the handshake within " +
                         std::to_string(options.timeout.count()) + " ms");
      break;
    }
    ++received;
    v1::Handshake hello;
    if (!hello.ParseFromString(envelope->header)) {
      problems.push_back("rank " + std::to_string(envelope->source) +
                         " sent a handshake that does not parse (different protocol?)");
      continue;
    }
    const std::string who = executableName(hello.role()) + " rank " +
                            std::to_string(envelope->source) + " on " + hello.hostname();
    if (hello.protocol_version() != options.protocolVersion) {
      problems.push_back(who + " speaks protocol version " +
                         std::to_string(hello.protocol_version()) + ", the display speaks " +
                         std::to_string(options.protocolVersion));
    }
    const auto expected = layoutVector(layout_);
    if (!std::equal(hello.layout().begin(), hello.layout().end(), expected.begin(),
                    expected.end())) {
      problems.push_back(who + " sees a different job layout");
    }
    placements.push_back({envelope->source,
                          hello.role(),
                          hello.hostname(),
                          {hello.cpus().begin(), hello.cpus().end()}});
  }
  v1::HandshakeReply reply;
  reply.set_accepted(problems.empty());
  reply.set_protocol_version(options.protocolVersion);
  for (std::uint32_t count : layoutVector(layout_)) reply.add_layout(count);
  std::string reason;
  for (const auto& problem : problems) reason += (reason.empty() ? "" : "; ") + problem;
  reply.set_reason(reason);
  v1::RunSettings settings = options.settings;
  if (settings.render_core_share().empty()) {  // auto: from where the processes run
    for (float share : renderCoreShares(placements)) settings.add_render_core_share(share);
  }
  if (!settings.has_need_gap_splats()) {
    // Where every render reads its data-sends' packets in place, a range
    // costs more than the bytes a gap adds (docs/scheduling.md §19).
    bool inPlace = !settings.no_shared_packets();
    for (int render : ranksOf(v1::ROLE_RENDER)) {
      for (int datasend : ranksOf(v1::ROLE_DATASEND)) {
        inPlace = inPlace && machines_[static_cast<std::size_t>(render)] ==
                                 machines_[static_cast<std::size_t>(datasend)];
      }
    }
    settings.set_need_gap_splats(inPlace ? kNeedGapSplatsInPlace : kNeedGapSplatsCopied);
  }
  *reply.mutable_settings() = settings;
  runSettings_ = settings;
  channel_->setPayloadTimeout(livenessOf(runSettings_).peerTimeout);
  std::vector<SendHandle> sends;
  for (int peer : peers) sends.push_back(channel.post(peer, MessageKind::HandshakeReply, reply));
  for (auto& send : sends) send.wait();
  if (!problems.empty()) throw CoordinatedError("handshake failed: " + reason);
}

void Job::markReady() {
  readyCpuSeconds_ = processCpuSeconds();
  activities_ = CpuActivities();
  readyWall_ = std::chrono::steady_clock::now();
}

void Job::reportReady(const std::string& detail) {
  v1::Ready ready;
  ready.set_role(role_);
  ready.set_world_rank(worldRank_);
  ready.set_detail(detail);
  channel_->send(displayRank(), MessageKind::Ready, ready);
  markReady();
}

std::vector<v1::Ready> Job::awaitReady(std::chrono::milliseconds timeout) {
  std::vector<v1::Ready> ready;
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (ready.size() + 1 < static_cast<std::size_t>(worldSize_)) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    auto envelope = channel_->receive(MPI_ANY_SOURCE, MessageKind::Ready,
                                      std::max(left, std::chrono::milliseconds(0)));
    if (!envelope) {
      throw TimeoutError("only " + std::to_string(ready.size()) + " of " +
                         std::to_string(worldSize_ - 1) + " processes reported ready within " +
                         std::to_string(timeout.count()) + " ms");
    }
    ready.push_back(envelope->as<v1::Ready>());
  }
  markReady();
  return ready;
}

void Job::acknowledgeShutdown(const std::string& summary) {
  v1::ShutdownAck ack;
  ack.set_role(role_);
  ack.set_world_rank(worldRank_);
  ack.set_summary(summary);
  ack.set_cpu_seconds_since_ready(processCpuSeconds() - readyCpuSeconds_);
  for (const auto& [activity, seconds] : activities_.totals()) {
    (*ack.mutable_cpu_seconds_by_activity())[activity] = seconds;
  }
  ack.set_wall_seconds_since_ready(
      std::chrono::duration<double>(std::chrono::steady_clock::now() - readyWall_).count());
  // Bounded: a display that went away after sending Shutdown must not keep
  // this process from ending.
  SendHandle handle = channel_->post(displayRank(), MessageKind::ShutdownAck, ack);
  const LivenessSettings liveness = livenessOf(runSettings_);
  if (!handle.waitFor(liveness.peerTimeout)) {
    std::vector<std::shared_ptr<const void>> keep;
    handle.abandon(keep);
    static std::vector<std::shared_ptr<const void>> abandoned;
    abandoned.insert(abandoned.end(), keep.begin(), keep.end());
    std::fprintf(stderr, "%s: the display did not take the shutdown acknowledgement\n",
                 describe().c_str());
  }
}

void Job::markLost(int rank) {
  if (rank == worldRank_ || !lost_.insert(rank).second) return;
  sends_->forget(rank);
  channel_->ignore(rank);
}

std::string Job::describeRank(int rank) const {
  for (v1::Role role : {v1::ROLE_DISPLAY, v1::ROLE_TRAVERSE, v1::ROLE_DATASEND, v1::ROLE_RENDER}) {
    const auto& ranks = ranksOf(role);
    if (std::find(ranks.begin(), ranks.end(), rank) != ranks.end()) {
      return executableName(role) + " rank " + std::to_string(rank);
    }
  }
  return "rank " + std::to_string(rank);
}

v1::Role Job::roleOf(int rank) const {
  for (v1::Role role : {v1::ROLE_DISPLAY, v1::ROLE_TRAVERSE, v1::ROLE_DATASEND, v1::ROLE_RENDER}) {
    const auto& ranks = ranksOf(role);
    if (std::find(ranks.begin(), ranks.end(), rank) != ranks.end()) return role;
  }
  return v1::ROLE_UNSPECIFIED;
}

void Job::shutdownAll(const std::string& reason, std::chrono::milliseconds timeout) {
  // Role by role, producers of work first: traverse processes stop ordering and
  // packing, data-send processes stop sending, render processes drain last.
  v1::Shutdown shutdown;
  shutdown.set_reason(reason);
  for (int rank : lost_) shutdown.add_lost_ranks(rank);
  acks_.clear();
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  for (v1::Role role : {v1::ROLE_TRAVERSE, v1::ROLE_DATASEND, v1::ROLE_RENDER}) {
    std::vector<SendHandle> sends;
    std::size_t expected = 0;
    for (int rank : ranksOf(role)) {
      if (lost_.contains(rank)) continue;  // gone: nothing to tell, nothing to wait for
      sends.push_back(channel_->post(rank, MessageKind::Shutdown, shutdown));
      ++expected;
    }
    std::size_t acked = 0;
    while (acked < expected) {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
          deadline - std::chrono::steady_clock::now());
      // Late messages (a re-issued tile, a work request) are received and
      // dropped so that their senders can finish.
      auto envelope = channel_->receive(MPI_ANY_SOURCE, std::nullopt,
                                        std::max(left, std::chrono::milliseconds(0)));
      if (!envelope) {
        throw TimeoutError("only " + std::to_string(acked) + " of " + std::to_string(expected) +
                           " " + roleName(role) + " processes acknowledged shutdown within " +
                           std::to_string(timeout.count()) + " ms");
      }
      if (envelope->kind == MessageKind::ShutdownAck && !lost_.contains(envelope->source)) {
        acks_.push_back(envelope->as<v1::ShutdownAck>());
        ++acked;
      }
    }
    for (auto& send : sends) send.wait();
  }
}

std::vector<int> Job::shutdownSurvivors(const std::string& reason,
                                        std::chrono::milliseconds timeout) {
  v1::Shutdown shutdown;
  shutdown.set_reason(reason);
  for (int rank : lost_) shutdown.add_lost_ranks(rank);
  acks_.clear();
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  std::set<int> waiting;
  std::vector<SendHandle> sends;
  for (v1::Role role : {v1::ROLE_TRAVERSE, v1::ROLE_DATASEND, v1::ROLE_RENDER}) {
    for (int rank : ranksOf(role)) {
      if (lost_.contains(rank)) continue;
      sends.push_back(channel_->post(rank, MessageKind::Shutdown, shutdown));
      waiting.insert(rank);
    }
  }
  Backoff backoff;
  while (!waiting.empty() && std::chrono::steady_clock::now() < deadline) {
    std::optional<Envelope> envelope;
    try {
      envelope = channel_->tryReceive();
    } catch (const PeerSilentError& silent) {
      markLost(silent.rank());
      continue;
    }
    if (!envelope) {
      backoff.wait();
      continue;
    }
    backoff.reset();
    if (envelope->kind == MessageKind::ShutdownAck && waiting.erase(envelope->source) > 0) {
      acks_.push_back(envelope->as<v1::ShutdownAck>());
    }
  }
  std::vector<std::shared_ptr<const void>> keep;
  for (auto& send : sends) {
    if (!send.test()) send.abandon(keep);
  }
  static std::vector<std::shared_ptr<const void>> abandoned;
  abandoned.insert(abandoned.end(), keep.begin(), keep.end());
  return {waiting.begin(), waiting.end()};
}

}  // namespace pointillist
