#include "traverse/traverse_role.hpp"

#include "common/mpi/role_options.hpp"
#include "common/mpi/serve.hpp"

namespace pointillist::traverse {

int runTraverseRole(Job& job, int argc, char** argv) {
  CLI::App app{"Pointillist traverse process (started by deploy/run.sh)"};
  CommonRoleOptions common;
  addCommonRoleOptions(app, common);
  if (!parseRoleOptions(app, job, argc, argv)) return 0;
  job.handshake(handshakeOptions(common));
  job.reportReady("");
  serveUntilShutdown(job, ServeHandlers{});
  return 0;
}

}  // namespace pointillist::traverse
