#include "common/core_share.hpp"

#include <sched.h>

#include <algorithm>
#include <map>
#include <set>

namespace pointillist {

std::vector<float> renderCoreShares(std::span<const ProcessPlacement> processes) {
  struct Host {
    std::set<std::uint32_t> cpus;
    std::size_t processes = 0;
    std::size_t unnamed = 0;  // processes that named no processor
  };
  std::map<std::string, Host> hosts;
  for (const ProcessPlacement& process : processes) {
    Host& host = hosts[process.host];
    ++host.processes;
    if (process.cpus.empty()) ++host.unnamed;
    host.cpus.insert(process.cpus.begin(), process.cpus.end());
  }
  std::vector<const ProcessPlacement*> renders;
  for (const ProcessPlacement& process : processes) {
    if (process.role == v1::ROLE_RENDER) renders.push_back(&process);
  }
  std::sort(renders.begin(), renders.end(),
            [](const ProcessPlacement* a, const ProcessPlacement* b) { return a->rank < b->rank; });
  std::vector<float> shares;
  shares.reserve(renders.size());
  for (const ProcessPlacement* render : renders) {
    const Host& host = hosts.at(render->host);
    const auto cores = static_cast<double>(host.cpus.size() + host.unnamed);
    shares.push_back(
        static_cast<float>(std::min(1.0, cores / static_cast<double>(host.processes))));
  }
  return shares;
}

std::vector<std::uint32_t> allowedCpus() {
  std::vector<std::uint32_t> cpus;
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof set, &set) != 0) return cpus;
  for (std::size_t cpu = 0; cpu < CPU_SETSIZE; ++cpu) {
    if (CPU_ISSET(cpu, &set)) cpus.push_back(static_cast<std::uint32_t>(cpu));
  }
  return cpus;
}

}  // namespace pointillist
