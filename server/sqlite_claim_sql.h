// SQL of the SQLite store's claim order (docs/operator_guide.md "Claim
// order") that tests explain as the store sends it. State values are
// inlined (QUEUED 1, RUNNING 2): the partial index jobs_claim_order needs
// its WHERE terms literally. The index is named: on a table without
// statistics the planner would pick jobs_state_owner and sort.
#pragma once

namespace nimbus::server {

// The highest priority among claimable QUEUED jobs: one index probe.
inline constexpr char kSqliteTopPrioritySql[] =
    "SELECT priority FROM jobs INDEXED BY jobs_claim_order WHERE state = 1 AND "
    "cancel_requested = 0 AND shards_pending = 0 ORDER BY priority DESC LIMIT 1";

// The first owner from ?2 (>=) or after it (>) with claimable QUEUED jobs
// at priority ?1, and its oldest such job.
#define NIMBUS_SQLITE_OWNER_SEEK(cmp)                                                  \
  "SELECT owner, create_time, rowid, id FROM jobs INDEXED BY jobs_claim_order "        \
  "WHERE state = 1 AND cancel_requested = 0 AND shards_pending = 0 AND priority = ?1 " \
  "AND owner " cmp " ?2 ORDER BY owner, create_time, rowid LIMIT 1"
inline constexpr char kSqliteOwnerSeekFromSql[] = NIMBUS_SQLITE_OWNER_SEEK(">=");
inline constexpr char kSqliteOwnerSeekAfterSql[] = NIMBUS_SQLITE_OWNER_SEEK(">");
#undef NIMBUS_SQLITE_OWNER_SEEK

}  // namespace nimbus::server
