#!/bin/sh
# The container's entry point: bring the database to the latest schema, then serve.
# Settings come from CONTEXTWEB_* variables (docs/operations.md); extra arguments go to
# `contextweb serve`. tests/test_docker_entrypoint.py runs this same script outside docker.
set -eu
contextweb migrate
exec contextweb serve "$@"
