#include "server/job_event_log.h"

#include <spdlog/spdlog.h>

#include <utility>

#include "server/bounded_text.h"
#include "server/job_view.h"

namespace nimbus::server {

void LogJobEvent(JobEventLog& log, const std::string& job_id, const char* kind,
                 std::vector<std::pair<std::string, std::string>> fields) {
  if (auto st = log.AppendEvent(job_id, {0, NowMs(), kind, std::move(fields)}); !st.ok())
    spdlog::warn("job={} event=event_log_failed kind={} reason=\"{}\"", job_id, kind,
                 BoundText(st.ToString(), 512));
}

}  // namespace nimbus::server
