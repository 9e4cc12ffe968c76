// SQL of the PostgreSQL store's claim order (docs/operator_guide.md "Claim
// order") that tests explain as the store sends it.
#pragma once

#include <cstdint>
#include <limits>

namespace nimbus::server {

// The highest priority of claimable QUEUED jobs below $1 (kAnyPriority:
// of all of them), from the top of jobs_claim_order.
inline constexpr char kTopPrioritySql[] =
    "SELECT priority FROM jobs WHERE state = 1 AND NOT cancel_requested AND "
    "shards_pending = 0 AND priority < $1 ORDER BY priority DESC LIMIT 1";
// Above every priority a job can have (0-100).
inline constexpr int32_t kAnyPriority = std::numeric_limits<int32_t>::max();

// The RUNNING job whose lease lapsed before $1 with the highest priority at
// least $2, oldest first, locked.
inline constexpr char kLapsedLeaseSql[] =
    "SELECT id, attempts FROM jobs WHERE state = 2 AND NOT cancel_requested AND "
    "shards_pending = 0 AND lease_expiry < $1 AND priority >= $2 "
    "ORDER BY priority DESC, create_time, seq LIMIT 1 FOR UPDATE SKIP LOCKED";

// Owner $2's oldest claimable QUEUED job at priority $1, locked.
inline constexpr char kOwnersOldestSql[] =
    "SELECT id, attempts FROM jobs WHERE state = 1 AND NOT cancel_requested AND "
    "shards_pending = 0 AND priority = $1 AND owner = $2 "
    "ORDER BY create_time, seq LIMIT 1 FOR UPDATE SKIP LOCKED";

// The owners with claimable QUEUED jobs at priority $1, in one round trip:
// a recursive walk of jobs_claim_order that seeks from each owner to the
// next (one index probe per owner, never a scan of their jobs); for each,
// its oldest such job, its RUNNING jobs and its last claim.
inline constexpr char kRankOwnersSql[] = R"sql(
WITH RECURSIVE owners(owner) AS (
  (SELECT owner FROM jobs WHERE state = 1 AND NOT cancel_requested AND shards_pending = 0
     AND priority = $1 ORDER BY owner LIMIT 1)
  UNION ALL
  SELECT (SELECT j.owner FROM jobs j WHERE j.state = 1 AND NOT j.cancel_requested
            AND j.shards_pending = 0 AND j.priority = $1 AND j.owner > o.owner
            ORDER BY j.owner LIMIT 1)
  FROM owners o WHERE o.owner IS NOT NULL)
SELECT o.owner, f.create_time, f.seq, f.id,
  (SELECT count(*) FROM jobs r WHERE r.state = 2 AND r.owner = o.owner),
  (SELECT coalesce(max(c.last_claim), 0) FROM owner_claims c WHERE c.owner = o.owner)
FROM owners o CROSS JOIN LATERAL (
  SELECT create_time, seq, id FROM jobs j WHERE j.state = 1 AND NOT j.cancel_requested
    AND j.shards_pending = 0 AND j.priority = $1 AND j.owner = o.owner
    ORDER BY j.create_time, j.seq LIMIT 1) f
WHERE o.owner IS NOT NULL
)sql";

}  // namespace nimbus::server
