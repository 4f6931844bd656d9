#!/bin/sh
# The container's entry point: bring the database to the latest schema, then serve. This and
# `make run` are where migrations run: `contextweb serve` never migrates, and exits 75 on a
# database that is not at the head revision (docs/operations.md).
# Settings come from CONTEXTWEB_* variables (docs/operations.md); extra arguments go to
# `contextweb serve`. tests/test_docker_entrypoint.py runs this same script outside docker.
#
# CONTEXTWEB_MIGRATE_ON_START (default true): false where another service migrates first, as in
# compose's `replicas` profile, where two API containers starting together would otherwise both run
# the migration on one PostgreSQL database (docs/deployment.md).
set -eu
case "${CONTEXTWEB_MIGRATE_ON_START:-true}" in
    true | 1 | yes | on)
        contextweb migrate
        ;;
    false | 0 | no | off)
        echo "entrypoint: CONTEXTWEB_MIGRATE_ON_START=${CONTEXTWEB_MIGRATE_ON_START}: not migrating, another service does"
        ;;
    *)
        echo "entrypoint: CONTEXTWEB_MIGRATE_ON_START must be true or false, not '${CONTEXTWEB_MIGRATE_ON_START}'" >&2
        exit 64
        ;;
esac
exec contextweb serve "$@"
