#pragma once
// The MPMD job: MPI start-up, role discovery, handshake and shutdown.
//
// Each role is its own executable started as one MPMD job
// (mpirun -np 1 pointillist-display : -np T pointillist-traverse : ...). Every
// process knows its own role; the roles of all ranks are exchanged once at
// start-up, so each process learns the layout and its peers without relying on
// the order of the mpirun command line.
#include <mpi.h>

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include "common/cpu_activity.hpp"
#include "common/job_layout.hpp"
#include "common/mpi/channel.hpp"
#include "common/mpi/send_queue.hpp"
#include "common/peer_ranks.hpp"
#include "pointillist.pb.h"

namespace pointillist {

// An error every process of the job has detected or been told about, so the
// job can end with a plain non-zero exit instead of MPI_Abort.
class CoordinatedError : public ProtocolError {
 public:
  using ProtocolError::ProtocolError;
};

struct HandshakeOptions {
  std::uint32_t protocolVersion = v1::PROTOCOL_VERSION_CURRENT;
  // Checked by the display when set: the counts the launcher asked for.
  std::optional<JobLayout> expectedLayout;
  std::chrono::milliseconds timeout{60'000};
  // Display: the run's settings, sent to every process in the handshake reply.
  v1::RunSettings settings;
};

class Job {
 public:
  // Initializes MPI (funneled threading: only the main thread calls MPI) and
  // discovers the layout. Throws ProtocolError when the layout is unusable.
  // Pointillist talks on its own duplicate of MPI_COMM_WORLD, so a library
  // sharing the process cannot match its messages.
  Job(int& argc, char**& argv, v1::Role role);
  ~Job();
  Job(const Job&) = delete;
  Job& operator=(const Job&) = delete;

  v1::Role role() const { return role_; }
  int worldRank() const { return worldRank_; }
  int worldSize() const { return worldSize_; }
  int appNumber() const { return appNumber_; }
  // Whether `rank` runs on this process's machine (common/shared_packets.hpp:
  // it can map this process's shared memory).
  bool onThisMachine(int rank) const;
  const JobLayout& layout() const { return layout_; }
  // World ranks holding a role, in rank order.
  const std::vector<int>& ranksOf(v1::Role role) const;
  int displayRank() const { return ranksOf(v1::ROLE_DISPLAY).front(); }
  PeerRanks peers() const;
  // This process's position among the ranks of its role (0-based).
  int indexInRole() const { return indexInRole_; }
  // A communicator holding only the ranks of this process's role.
  MPI_Comm roleComm() const { return roleComm_; }
  Channel& channel() { return *channel_; }
  // Sends in flight; the serve loop reaps them.
  SendQueue& sends() { return *sends_; }
  // The main thread's CPU time per activity since Ready, sent with the shutdown ack.
  CpuActivities& activities() { return activities_; }
  std::string describe() const;              // "pointillist-render rank 5"
  std::string describeRank(int rank) const;  // any rank of the job, the same way
  v1::Role roleOf(int rank) const;

  // `rank` is gone: sends to it are abandoned and dropped from now on, and
  // shutdown neither tells it nor waits for it.
  void markLost(int rank);
  bool lost(int rank) const { return lost_.contains(rank); }
  const std::set<int>& lostRanks() const { return lost_; }

  // Every process reports to the display, which checks protocol versions and
  // role counts and answers each one; a mismatch is a ProtocolError everywhere.
  // The display's run settings come back in the reply (runSettings()).
  void handshake(const HandshakeOptions& options);
  const v1::RunSettings& runSettings() const { return runSettings_; }
  // Non-display: report Ready, then wait for Shutdown while calling onMessage
  // for every other message (the role's work loop).
  // Display: send Shutdown to every other rank and collect their acks.
  void shutdownAll(const std::string& reason, std::chrono::milliseconds timeout);
  // Display, after a lost process: Shutdown to every live process at once,
  // acks collected until `timeout`; never throws for a peer that does not
  // answer. Returns the processes that did not acknowledge.
  std::vector<int> shutdownSurvivors(const std::string& reason, std::chrono::milliseconds timeout);
  void reportReady(const std::string& detail);
  std::vector<v1::Ready> awaitReady(std::chrono::milliseconds timeout);
  std::vector<v1::ShutdownAck> lastAcks() const { return acks_; }
  // Answers a Shutdown message (non-display roles).
  void acknowledgeShutdown(const std::string& summary);
  // Marks the start of the idle/work period measured in ShutdownAck.
  void markReady();

  // True once MPI_Finalize may be skipped because peers were told to abort.
  void finalize();

 private:
  v1::Role role_;
  int worldRank_ = 0;
  int worldSize_ = 0;
  int appNumber_ = -1;
  int indexInRole_ = 0;
  std::vector<std::uint64_t> machines_;  // per world rank: thisMachineIdentity()
  JobLayout layout_;
  std::vector<std::vector<int>> ranksByRole_;
  MPI_Comm comm_ = MPI_COMM_NULL;  // our duplicate of MPI_COMM_WORLD
  MPI_Comm roleComm_ = MPI_COMM_NULL;
  std::unique_ptr<Channel> channel_;
  std::unique_ptr<SendQueue> sends_;
  v1::RunSettings runSettings_;
  std::vector<v1::ShutdownAck> acks_;
  double readyCpuSeconds_ = 0.0;
  CpuActivities activities_;
  std::chrono::steady_clock::time_point readyWall_;
  bool finalized_ = false;
  std::set<int> lost_;
};

const char* roleName(v1::Role role);        // "display"
std::string executableName(v1::Role role);  // "pointillist-display"
double processCpuSeconds();

}  // namespace pointillist
