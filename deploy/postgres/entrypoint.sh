#!/bin/sh
# Starts PostgreSQL on $NIMBUS_DB_LISTEN:$PGPORT (addresses as in
# listen_addresses; the image's default 127.0.0.1) with the data in $PGDATA,
# in the foreground (SIGINT: fast shutdown). On an
# empty data folder it first creates the cluster and the role and database
# nimbus (password $NIMBUS_DB_PASSWORD, required).
set -eu
bin=/usr/lib/postgresql/15/bin
: "${NIMBUS_DB_PASSWORD:?set NIMBUS_DB_PASSWORD}"
if [ ! -s "$PGDATA/PG_VERSION" ]; then
  pwfile=$(mktemp)
  printf '%s\n' "$NIMBUS_DB_PASSWORD" >"$pwfile"
  "$bin/initdb" -D "$PGDATA" -U postgres --pwfile="$pwfile" \
    --auth-local=trust --auth-host=scram-sha-256 >/dev/null
  rm -f "$pwfile"
  "$bin/postgres" --single -D "$PGDATA" -c unix_socket_directories= postgres >/dev/null <<SQL
CREATE ROLE nimbus LOGIN PASSWORD '$NIMBUS_DB_PASSWORD';
CREATE DATABASE nimbus OWNER nimbus;
SQL
fi
exec "$bin/postgres" -D "$PGDATA" -c "listen_addresses=$NIMBUS_DB_LISTEN" -p "$PGPORT" \
  -c unix_socket_directories= "$@"
